"""An origin's programs as records that outlive its process.

How this works: a node that keeps a durable record (``ramps.runtime.store``)
writes one ``OriginRecord`` per program it owns and has not delivered yet,
each time the program changes (``Origin.changed`` names them), before it acts
on the change: an offer is recorded before it is sent. A node that starts
with records resumes them (``Origin.restore``):

- a program whose current attempt ran on another robot is offered there
  again, the same attempt (and again once that host's liveliness is heard,
  as the first offer may precede the link): a host that still runs it says
  yes again and starts nothing, and its heartbeats and result come to this
  robot's name as before; a host that never got the offer (it went down
  with the old process) or no longer has it (it restarted too, or stopped
  the program when this robot was gone longer than ``origin_hold``) starts
  it, from its latest checkpoint; a host that never answers within the
  restart's grace (``RESTORE_GRACE``) is written off like any silent one
  and the program placed elsewhere;
- a program that ran here, or was backing off, is placed again at once (its
  copy died with the old process), from its latest checkpoint.

A record keeps what the program needs to be placed again (the submission,
its arguments and checkpoint) and to recognise its live copies (attempts
and hosts); timers and estimates are not kept: they start afresh.

Rules: no clock, no I/O; bytes in, bytes out (msgpack via msgspec).
``restore`` is a function of the origin it resumes programs for, which it
sees as a ``RestoringOrigin``.
"""

from __future__ import annotations

from typing import Protocol

import msgspec

from ramps.core.events import Action, Note, Submit
from ramps.core.program import AutonomousProgram, Event, ProgramState
from ramps.core.timers import Timers

#: seconds a resumed program waits to hear of its host before it is written off
RESTORE_GRACE = 10.0
#: the record's format; a record of another format is not read
RECORD_FORMAT = 1


class OriginRecord(msgspec.Struct, frozen=True, kw_only=True):
    """One program an origin owns, as it stands."""

    submit: Submit
    #: the current attempt, its host, and every attempt whose result is still wanted
    attempt: int = 0
    host: str = ""
    live: dict[int, str] = {}
    #: attempts made, failures and moves so far (``AutonomousProgram``)
    made: int = 0
    failures: int = 0
    moves: int = 0
    ran_on: list[str] = []
    #: the latest saved state and how far it was, if any
    checkpoint: bytes | None = None
    checkpoint_fraction: float = 0.0
    state: str = "offered"


_encoder = msgspec.msgpack.Encoder()
_decoder = msgspec.msgpack.Decoder(OriginRecord)


def record_of(ap: AutonomousProgram) -> OriginRecord:
    return OriginRecord(submit=ap.submit, attempt=ap.attempt, host=ap.host or "", live=dict(ap.live), made=ap.made,
                        failures=ap.failures, moves=ap.moves, ran_on=list(ap.ran_on), checkpoint=ap.checkpoint,
                        checkpoint_fraction=ap.checkpoint_fraction, state=ap.state.value)


def same_to_restore(old: OriginRecord, new: OriginRecord) -> bool:
    """Whether a node restarted with ``old`` in its record resumes the program
    as it would with ``new``: they differ at most in ``state``, which
    ``program_of`` does not read, and in ``new.ran_on`` naming the current
    host as well (what an acceptance changes: the restarted origin offers
    that attempt to that host again, and its yes names it again), so a
    node need not write ``new``."""
    if new.ran_on != old.ran_on and new.ran_on != [*old.ran_on, new.host]:
        return False
    return msgspec.structs.replace(new, state=old.state, ran_on=old.ran_on) == old


def encode_record(rec: OriginRecord) -> bytes:
    return _encoder.encode(rec)


def decode_record(data: bytes) -> OriginRecord:
    """The record in ``data``; ``msgspec.DecodeError`` (a ``ValueError``) if
    it is not one."""
    return _decoder.decode(data)


def program_of(rec: OriginRecord, now: float) -> AutonomousProgram:
    """The program a record describes, not yet placed anywhere by this
    process (``Origin.restore`` decides what happens to it). Its deadline,
    if it had one, is dropped: it was a time of the old process's clock."""
    sub = rec.submit if rec.submit.deadline is None else msgspec.structs.replace(rec.submit, deadline=None)
    ap = AutonomousProgram(sub, now)
    ap.attempt = rec.attempt
    ap.host = rec.host or None
    ap.live = dict(rec.live)
    ap.made = max(rec.made, rec.attempt, max(rec.live, default=0))
    ap.failures = rec.failures
    ap.moves = rec.moves
    ap.ran_on = dict.fromkeys(rec.ran_on)
    ap.checkpoint = rec.checkpoint
    ap.checkpoint_fraction = rec.checkpoint_fraction
    ap.state = ProgramState.BACKOFF  # Origin.restore makes it offered again, or places it
    return ap


class RestoringOrigin(Protocol):
    """What ``restore`` reads and changes of ``ramps.core.origin.Origin``."""

    me: str
    programs: dict[str, AutonomousProgram]
    #: host -> the ids of its live programs, in placement order
    by_host: dict[str, dict[str, None]]
    hosts_of: dict[str, set[str]]
    #: restored programs offered to their host again and not answered yet: id -> attempt
    resumed: dict[str, int]
    timers: Timers

    def add_policy(self, name: str) -> None: ...

    def work_estimate(self, sub: Submit) -> float: ...

    def offer(self, ap: AutonomousProgram, out: list[Action]) -> None: ...


def restore(origin: RestoringOrigin, programs: list[AutonomousProgram], now: float, out: list[Action]) -> None:
    """Resume ``programs`` (``program_of``) in ``origin``: one whose current
    attempt ran on a teammate waits ``RESTORE_GRACE`` to hear of it there,
    as if just offered; one that ran here or was backing off is placed
    again now."""
    for ap in programs:
        if ap.program_id in origin.programs:
            raise ValueError(f"program id {ap.program_id!r} is already here")
        sub = ap.submit
        if sub.policy:
            try:
                origin.add_policy(sub.policy)
            except ValueError:  # a policy this version does not have: the node's own places it
                ap.submit = msgspec.structs.replace(sub, policy="")
        origin.programs[ap.program_id] = ap
        for attempt, host in list(ap.live.items()):
            if host == origin.me:  # its copy here died with the previous process
                del ap.live[attempt]
            else:
                origin.by_host.setdefault(host, {})[ap.program_id] = None
                origin.hosts_of.setdefault(ap.program_id, set()).add(host)
        out.append(Note(what="restored", program_id=ap.program_id, robot=ap.host or "", attempt=ap.attempt,
                        detail=f"{len(ap.live)} live cop{'y' if len(ap.live) == 1 else 'ies'}"))
        if ap.host is not None and ap.live.get(ap.attempt) == ap.host:
            # offered there again: a host that has it says yes again, one
            # that never got it (the offer went down with the old process)
            # or lost it (it restarted too) takes it now; the offer goes
            # again when the host's liveliness is heard (the first may
            # precede the link)
            ap.state = ProgramState.OFFERED
            ap.last_heard = ap.placed_at = ap.accepted_at = ap.done_at = now
            resume = ap.checkpoint is not None
            ap.work = origin.work_estimate(ap.submit) * (1.0 - (ap.checkpoint_fraction if resume else 0.0))
            ap.resumed_from = ap.checkpoint_fraction if resume else None
            origin.resumed[ap.program_id] = ap.attempt
            origin.offer(ap, out)
            origin.timers.set(ap, now + RESTORE_GRACE, Event.CONNECT_TIMEOUT)
        else:
            ap.state = ProgramState.BACKOFF
            origin.timers.set(ap, now, Event.BACKOFF_DONE)


def offer_again(origin: RestoringOrigin, robot: str, out: list[Action]) -> None:
    """``robot``'s liveliness is heard: offer it again the restored programs
    offered to it and not answered yet (the first offer may have preceded
    the link); forget those answered meanwhile."""
    for pid, attempt in list(origin.resumed.items()):
        ap = origin.programs.get(pid)
        if ap is None or ap.state is not ProgramState.OFFERED or ap.attempt != attempt:
            del origin.resumed[pid]
        elif ap.host == robot:
            origin.offer(ap, out)
