"""A move: a running program offered to a better host while its copy runs on.

How this works: ``ramps.core.relocation`` decides that a running program
should move and where (eq. (1) with its thresholds); the move itself is the
``MOVING`` state of the program's state machine, and these are its
transitions. ``start`` keeps the running copy's attempt and estimates in
``AutonomousProgram.moving_from`` and offers a new attempt where the
relocation priced it (from the latest checkpoint, if any). When the new
host accepts (``moved``), the old copy is cancelled (``drop_old_copy``);
until then a result from either copy is delivered and the other stopped. A
refusal or failure of the new host (``move_failed``) gives the move up
(``abandon``): the program goes back to its old copy, still running, or,
if that copy is gone too, backs off and is placed again.

Rules: functions of the origin they act for, which they see as a
``MovingOrigin``; no clock, no I/O.
"""

from __future__ import annotations

from typing import Any, Protocol

from ramps.core.config import RampsConfig
from ramps.core.events import Action, Note, Send
from ramps.core.loadview import LoadView
from ramps.core.messages import CancelProgram
from ramps.core.policy import Placement
from ramps.core.program import AutonomousProgram, Event, ProgramState
from ramps.core.timers import Timers

S = ProgramState
E = Event


class MovingOrigin(Protocol):
    """What a move reads and changes of ``ramps.core.origin.Origin``."""

    me: str
    view: LoadView
    config: RampsConfig
    timers: Timers
    #: host -> the ids of its live programs, in placement order
    by_host: dict[str, dict[str, None]]
    moves: int
    moves_aborted: int
    rejections: int
    host_failures: int

    def place(self, ap: AutonomousProgram, now: float, out: list[Action], *, host: str | None = None,
              placement: Placement | None = None, prefer: tuple[str, float] = ("", 0.0)) -> None: ...

    def accept(self, ap: AutonomousProgram, now: float, out: list[Action], msg: Any) -> None: ...

    def backoff(self, ap: AutonomousProgram, now: float, out: list[Action], *, certain: bool = False) -> None: ...

    def leave_host(self, ap: AutonomousProgram, host: str | None, finish_seq: int | None,
                   *, attempt: int | None = None) -> None: ...


def start(origin: MovingOrigin, ap: AutonomousProgram, placement: Placement, now: float, out: list[Action]) -> None:
    """Offer the program to its new host; the old copy runs on meanwhile."""
    old = [ap.attempt, ap.host, ap.last_heard, ap.done, ap.done_at, ap.work, ap.resumed_from, ap.accepted_at,
           ap.placed_at, ap.stall_base]
    ap.moves += 1
    origin.moves += 1
    ap.move_wanted_since = None
    ap.moving_from = old
    # the budget is what staying costs, less the thresholds (``ramps.core.relocation.price_move``)
    budget = "" if placement.time_budget is None else f", budget {placement.time_budget:.1f} s"
    out.append(Note(what="moving", program_id=ap.program_id, robot=placement.host, attempt=ap.attempt,
                    detail=f"from {ap.host}: expected {placement.expected_time:.1f} s there{budget}"))
    origin.place(ap, now, out, placement=placement)
    ap.state = S.MOVING


def moved(origin: MovingOrigin, ap: AutonomousProgram, now: float, out: list[Action], msg: Any) -> None:
    """The new host took the program: stop the old copy."""
    drop_old_copy(origin, ap, out)
    origin.accept(ap, now, out, msg)
    out.append(Note(what="moved", program_id=ap.program_id, robot=ap.placed_host, attempt=ap.attempt,
                    detail="" if ap.resumed_from is None else f"resumed from {ap.resumed_from:.3f}"))


def drop_old_copy(origin: MovingOrigin, ap: AutonomousProgram, out: list[Action] | None = None) -> None:
    """The copy a move takes over from is no longer wanted (``out``: tell
    its host to stop it) or is gone with its host (``out`` None)."""
    old, ap.moving_from = ap.moving_from, None
    if old is None or ap.live.get(old[0]) != old[1]:
        return
    attempt, host = old[0], old[1]
    ap.live.pop(attempt, None)
    origin.leave_host(ap, host, None, attempt=attempt)
    if out is not None:
        out.append(Send(to=host, msg=CancelProgram(program_id=ap.program_id, attempt=attempt, origin=origin.me)))
    if host not in ap.live.values():
        origin.by_host.get(host, {}).pop(ap.program_id, None)


def move_failed(origin: MovingOrigin, ap: AutonomousProgram, now: float, out: list[Action], msg: Any,
                event: Event) -> None:
    """The new host turned the move away, never accepted, or was lost."""
    host = ap.placed_host
    if event == E.REJECTED:
        origin.rejections += 1
        if msg.report is not None and origin.view.on_report(msg.report, now, fresh=True):
            out.append(Note(what="unblacklisted", robot=msg.report.robot))
        if msg.permanent:
            ap.moves = origin.config.relocate_max_moves  # that host never will; nor try others
        elif msg.reason == "late":
            # the program did not move, and what the host protects ends by
            # its deadlines: a later check may try again
            ap.moves -= 1
        why = f"{host} refused: {msg.reason}"
    else:
        origin.host_failures += 1
        if event == E.CONNECT_TIMEOUT:
            out.append(Send(to=host, msg=CancelProgram(program_id=ap.program_id, attempt=ap.attempt,
                                                       origin=origin.me)))
        if origin.view.blacklist(host):
            out.append(Note(what="blacklisted", robot=host, program_id=ap.program_id, detail=event))
        why = f"{host}: {event}"
    abandon(origin, ap, now, out, why)


def abandon(origin: MovingOrigin, ap: AutonomousProgram, now: float, out: list[Action], why: str) -> None:
    """The new copy will not run: go back to the old one, or, if that is
    gone too, place the program again after a short back-off."""
    origin.moves_aborted += 1
    host, attempt = ap.host, ap.attempt
    origin.leave_host(ap, host, None)
    ap.live.pop(attempt, None)
    if host not in ap.live.values():
        origin.by_host.get(host or "", {}).pop(ap.program_id, None)
    old, ap.moving_from = ap.moving_from, None
    out.append(Note(what="move_aborted", program_id=ap.program_id, robot=host or "", attempt=attempt,
                    detail=why))
    ap.deadline = None
    if old is not None and ap.live.get(old[0]) == old[1]:
        (ap.attempt, ap.host, ap.last_heard, ap.done, ap.done_at, ap.work, ap.resumed_from,
         ap.accepted_at, ap.placed_at, ap.stall_base) = old
        ap.state = S.RUNNING
        origin.timers.set(ap, max(now, ap.last_heard + origin.config.heartbeat_timeout), E.HEARTBEAT_TIMEOUT)
        return
    ap.failures += 1
    origin.backoff(ap, now, out, certain=True)
