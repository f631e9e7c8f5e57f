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
"""

from __future__ import annotations

import msgspec

from ramps.core.events import Submit
from ramps.core.program import AutonomousProgram, ProgramState

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
