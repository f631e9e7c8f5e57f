"""When an attempt fails: rejections, host failures, lost workers, and the back-off.

How this works: these are the origin's transitions for an attempt that
will not deliver (``ramps.core.program.TRANSITIONS``):

- **turned away** (``on_rejected``): a permanent refusal fails the program;
  otherwise the host's fresh report goes into the view, the host is
  avoided unless it was only busy, and the program is placed again at
  once, or after a random contention back-off (doubling) when turned away
  again and again, as several origins place on the same few robots;
- **host failed** (``on_host_failed``: no acceptance in time, silence, or
  its session gone): a host still heard from (``ramps.core.liveness``:
  anything since, or a load report not yet overdue) lost messages, not
  the program, so its copy stays wanted while the program runs elsewhere too;
  an origin cut off from everyone keeps the remote copy wanted and runs
  the program here; otherwise the attempt is written off
  (``ramps.core.isolation`` may revive it), the host blacklisted, and the
  program backs off (``backoff``: the paper's random wait, short when the
  host is certainly gone) and is placed again, until ``max_attempts``;
- **worker lost** (``worker_lost``: the host lives, the worker under the
  program died): placed again elsewhere at once, with no blacklist and no
  back-off, unless another copy may still deliver, a move is under way, or
  its workers died by themselves often enough to make it a poison pill.

Rules: functions of the origin they act for, which they see as a
``FailingOrigin``; no clock, no I/O, waits drawn from the origin's ``rng``.
"""

from __future__ import annotations

import random
from typing import Protocol

from ramps.core.config import RampsConfig
from ramps.core.events import Action, Note, Send
from ramps.core.isolation import Isolation
from ramps.core.liveness import still_heard
from ramps.core.loadview import LoadView
from ramps.core.messages import CancelProgram, OffloadRejected, ProgramResult
from ramps.core.policy import Placement
from ramps.core.program import AutonomousProgram, Event, ProgramState, poison_error, poison_pill
from ramps.core.timers import Timers

S = ProgramState
E = Event


class FailingOrigin(Protocol):
    """What failures read and change of ``ramps.core.origin.Origin``."""

    me: str
    view: LoadView
    config: RampsConfig
    rng: random.Random
    timers: Timers
    isolation: Isolation
    heard: dict[str, float]
    host_failures: int
    rejections: int

    def place(self, ap: AutonomousProgram, now: float, out: list[Action], *, host: str | None = None,
              placement: Placement | None = None, prefer: tuple[str, float] = ("", 0.0)) -> None: ...

    def deliver(self, ap: AutonomousProgram, now: float, out: list[Action], *, ok: bool,
                value: bytes = b"", error: str = "", host: str = "", kind: str = "") -> None: ...

    def leave_host(self, ap: AutonomousProgram, host: str | None, finish_seq: int | None,
                   *, attempt: int | None = None) -> None: ...

    def abandon_move(self, ap: AutonomousProgram, now: float, out: list[Action], why: str) -> None: ...


def on_rejected(origin: FailingOrigin, ap: AutonomousProgram, now: float, out: list[Action],
                msg: OffloadRejected) -> None:
    """The host turned the current attempt away."""
    origin.rejections += 1
    host = ap.placed_host
    origin.leave_host(ap, host, None)
    ap.live.pop(ap.attempt, None)
    out.append(Note(what="rejected", program_id=ap.program_id, robot=host, attempt=ap.attempt,
                    detail=f"{msg.reason}: {msg.detail}"))
    if msg.permanent:
        origin.deliver(ap, now, out, ok=False, error=f"{host} refused program {ap.submit.program!r}: {msg.reason}"
                       + (f" ({msg.detail})" if msg.detail else ""), host=host, kind="refused")
        return
    if msg.report is not None and origin.view.on_report(msg.report, now, fresh=True):
        out.append(Note(what="unblacklisted", robot=msg.report.robot))
    ap.rejections += 1
    if msg.reason != "busy" or msg.report is None:
        # a busy host sent its true load, which the view now holds: it may
        # still be the best choice (the origin then expects what it has)
        ap.excluded.add(host)
    if host == origin.me and msg.reason == "closing":
        # this robot is shutting down: a local_only program (or any, when
        # no teammate is left) would be offered here again at once and
        # turned away forever; wait instead (the driver cancels it)
        backoff(origin, ap, now, out)
        return
    if ap.rejections >= 2 and origin.config.contention_backoff > 0 and msg.reason != "late":
        # turned away again: several origins are placing on the same few
        # robots at this moment; wait a random moment (doubling) so their
        # prompt reports arrive before this program tries again
        wait = origin.rng.uniform(0.0, origin.config.contention_backoff * 2 ** (ap.rejections - 2))
        _wait(origin, ap, now, out, wait, f"{wait:.3f} after {ap.rejections} rejections")
        return
    origin.place(ap, now, out)


def on_host_failed(origin: FailingOrigin, ap: AutonomousProgram, now: float, out: list[Action],
                   reason: Event) -> None:
    """The current attempt's host failed: no acceptance in time, silence, or its session gone."""
    host = ap.placed_host
    origin.host_failures += 1
    ap.failures += 1
    ap.deadline = None
    out.append(Note(what="failed", program_id=ap.program_id, robot=host, attempt=ap.attempt, detail=reason))
    if _still_publishing(origin, host, reason, now):
        # the host says it is alive (load reports after we last heard about
        # this program): messages about the program were lost, not the
        # host. Keep its copy wanted and run the program elsewhere too.
        out.append(Note(what="suspected", program_id=ap.program_id, robot=host, attempt=ap.attempt,
                        detail=f"{reason}, but the host still publishes: its copy stays wanted"))
        ap.excluded.add(host)
        origin.place(ap, now, out)
        return
    if host != origin.me and origin.view.isolated(now, origin.config.isolation_timeout):
        # we are the ones cut off: keep the remote attempt's result wanted
        # and run the program here meanwhile; first result wins
        out.append(Note(what="isolated", program_id=ap.program_id, robot=host, attempt=ap.attempt))
        origin.place(ap, now, out, host=origin.me)
        return
    origin.leave_host(ap, host, None)
    ap.live.pop(ap.attempt, None)
    if host != origin.me and reason in (E.HOST_LOST, E.HEARTBEAT_TIMEOUT):
        origin.isolation.wrote_off(ap, ap.attempt, host, now)
    else:
        # a host that just went silent is not told: the message could not
        # arrive, and on Zenoh, sending to a cut-off peer can stall this
        # robot's traffic for seconds. If it is alive, its next heartbeat
        # or acceptance gets a cancel (``Origin._route``).
        out.append(Send(to=host, msg=CancelProgram(program_id=ap.program_id, attempt=ap.attempt,
                                                   origin=origin.me)))
    if origin.view.blacklist(host):
        out.append(Note(what="blacklisted", robot=host, program_id=ap.program_id, detail=reason))
    # a host whose session is gone (connection reset, lease expired) is
    # certainly unreachable: its programs need only a short jitter, since
    # hosts' admission and prompt reports keep the origins re-placing at
    # once from piling up; silence (a timeout) keeps the paper's back-off
    backoff(origin, ap, now, out, certain=reason == E.HOST_LOST)


def _still_publishing(origin: FailingOrigin, host: str | None, reason: Event, now: float) -> bool:
    """Whether ``host`` outlived the silence about a program (``ramps.core.liveness``)."""
    config, view = origin.config, origin.view
    if not config.hedge_suspects or host is None or host == origin.me or view.is_lost(host):
        return False
    window = {E.HEARTBEAT_TIMEOUT: config.heartbeat_timeout, E.CONNECT_TIMEOUT: config.connect_timeout}.get(reason)
    if window is None:
        return False
    at = origin.heard.get(host)
    return still_heard(config, window, None if at is None else now - at, view.report_age(host, now),
                       view.report_gap(host))


def backoff(origin: FailingOrigin, ap: AutonomousProgram, now: float, out: list[Action], *,
            certain: bool = False) -> None:
    """Wait a random back-off (short when the host is ``certain``\\ly gone),
    then place the program again; give up after ``max_attempts`` failures."""
    if ap.failures >= origin.config.max_attempts:
        origin.deliver(ap, now, out, ok=False, host=ap.host or "", kind="failed",
                       error=f"gave up after {ap.failures} failed attempts")
        return
    wait = origin.rng.uniform(0.0, origin.config.backoff_lost_max if certain else origin.config.backoff_max)
    _wait(origin, ap, now, out, wait, f"{wait:.3f}")


def _wait(origin: FailingOrigin, ap: AutonomousProgram, now: float, out: list[Action], wait: float,
          detail: str) -> None:
    """Back off for ``wait`` seconds, then place the program again."""
    ap.state = S.BACKOFF
    out.append(Note(what="backoff", program_id=ap.program_id, attempt=ap.attempt, detail=detail))
    origin.timers.set(ap, now + wait, E.BACKOFF_DONE)


def worker_lost(origin: FailingOrigin, ap: AutonomousProgram, msg: ProgramResult, now: float,
                out: list[Action]) -> None:
    """The worker died under the program (``ProgramResult.retryable``), not
    the program's own error: run it elsewhere, unless something else decides."""
    origin.leave_host(ap, msg.host, msg.finish_seq, attempt=msg.attempt)
    ap.live.pop(msg.attempt, None)
    ap.failures += 1
    out.append(Note(what="failed", program_id=ap.program_id, robot=msg.host, attempt=msg.attempt,
                    detail=f"worker lost: {msg.error}"))
    if msg.worker_died:
        ap.deaths.append((msg.attempt, msg.host, msg.error))
    if ap.state is S.MOVING:
        if msg.attempt == ap.attempt:  # the new copy died: the old one runs on
            origin.abandon_move(ap, now, out, f"worker lost on {msg.host}")
        elif ap.moving_from is not None and ap.moving_from[0] == msg.attempt:
            ap.moving_from = None  # the old copy died: the move goes on
        return
    if ap.live:
        return  # another live attempt may still deliver
    ap.deadline = None
    if poison_pill(ap.deaths):
        origin.deliver(ap, now, out, ok=False, host=msg.host, kind="program", error=poison_error(ap.deaths))
        return
    if ap.failures >= origin.config.max_attempts:
        backoff(origin, ap, now, out)  # delivers the error
        return
    # not a host failure (no blacklist, no back-off): run it elsewhere now
    ap.excluded.add(msg.host)
    origin.place(ap, now, out)
