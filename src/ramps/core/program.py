"""The autonomous program: its states, its events, and the one table of legal
transitions.

How this works: an autonomous program (AP) is created on its origin robot by
``Submit``. It places itself with the origin's policy, offers its parameters
to the chosen host (``OFFERED``), runs there under heartbeat watch
(``RUNNING``), and ends exactly once (``DONE``/``FAILED``) by delivering its
result or a clear error. When its host fails (no acceptance in time, silence,
or the transport reports the host lost) it blacklists the host, waits a
random back-off (``BACKOFF``) and places itself again; when a host turns it
away because it is busier than the origin thought, it re-places at once.
Relocation (``MOVING``): the program runs on its old host while a new
attempt is offered to the new one; whichever result comes first is
delivered and the other copy cancelled; if the new host turns it away or
fails, the old copy simply keeps running.

``TRANSITIONS[state][event]`` is a ``Transition``: the handler (a method of
``ramps.core.origin.Origin``, by name; ``Origin`` resolves every name once,
when its module is imported, so a typo fails at import) and the states the
handler may leave the program in, each with the condition for it. The
origin runs the handler, then checks the program's new state against that
list: a handler that leaves it anywhere else raises ``IllegalTransition``
(a bug on this robot, never a peer's doing). ``ramps.core.diagram`` draws
the state diagram in ``docs/state-machine.md`` from this same table; read
the table there rather than here.

Events about an attempt other than the current one never reach the table:
the origin settles them first (cancel the stray copy, or discard a stale
result). A pair missing from the table is a ``ProtocolError`` naming the
program, state and event: for remote input the origin counts it as an
anomaly and drops it; for local misuse it raises.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from enum import StrEnum
from collections.abc import Callable, Mapping
from typing import Any

from ramps.core.events import Submit


class ProgramState(StrEnum):
    OFFERED = "offered"
    RUNNING = "running"
    BACKOFF = "backoff"
    MOVING = "moving"
    DONE = "done"
    FAILED = "failed"


class Event(StrEnum):
    """What can happen to a program (a message about its current attempt, a
    timer, the transport, or the application)."""

    #: the host took the offer (``OffloadAccepted``)
    ACCEPTED = "accepted"
    #: the host turned it away (``OffloadRejected``)
    REJECTED = "rejected"
    #: no acceptance within ``connect_timeout`` (timer)
    CONNECT_TIMEOUT = "connect_timeout"
    #: the transport says the host's session is gone
    HOST_LOST = "host_lost"
    #: the host says the program still runs (``Heartbeat``)
    HEARTBEAT = "heartbeat"
    #: no heartbeat within ``heartbeat_timeout`` (timer)
    HEARTBEAT_TIMEOUT = "heartbeat_timeout"
    #: the host sent the program's result (``ProgramResult``)
    RESULT = "result"
    #: the random back-off is over (timer)
    BACKOFF_DONE = "backoff_done"
    #: a relocation check found a much better host (eq. 1)
    RELOCATE = "relocate"
    #: the application cancelled the program
    CANCEL = "cancel"


class ProtocolError(Exception):
    """An event that has no transition from the program's current state."""

    def __init__(self, program_id: str, state: ProgramState, event: str) -> None:
        super().__init__(f"program {program_id}: no transition from state {state.value!r} on event {str(event)!r}")
        self.program_id = program_id
        self.state = state
        self.event = event


class IllegalTransition(ProtocolError):
    """A handler left a program in a state its transition does not allow: a
    bug in the origin, raised whatever caused the event."""

    def __init__(self, program_id: str, state: ProgramState, event: str, handler: str,
                 got: ProgramState, allowed: frozenset[ProgramState]) -> None:
        Exception.__init__(
            self, f"program {program_id}: handler {handler!r} for event {str(event)!r} in state {state.value!r} "
            f"left it {got.value!r}; allowed: {', '.join(sorted(s.value for s in allowed))}")
        self.program_id = program_id
        self.state = state
        self.event = event
        self.handler = handler
        self.got = got
        self.allowed = allowed


@dataclass(frozen=True, slots=True)
class Outcome:
    """One state a handler may leave the program in, and when."""

    #: the next state; ``None``: the program stays where it was
    state: ProgramState | None
    #: the condition, in a few words (drawn on the diagram's edge)
    when: str = ""


@functools.cache
def _allowed(transition: "Transition", state: ProgramState) -> frozenset[ProgramState]:
    """``Transition.allowed``, worked out once per transition and state (the table is fixed)."""
    return frozenset(state if o.state is None else o.state for o in transition.outcomes)


@dataclass(frozen=True, slots=True)
class Transition:
    """What an event does in one state: run ``handler``, end in one of ``outcomes``."""

    #: the ``Origin`` method that handles it, without its leading underscore
    handler: str
    outcomes: tuple[Outcome, ...]

    def allowed(self, state: ProgramState) -> frozenset[ProgramState]:
        """The states the program may be in after the handler ran from ``state``."""
        return _allowed(self, state)


S = ProgramState
E = Event


def _t(handler: str, *outcomes: tuple[ProgramState | None, str]) -> Transition:
    return Transition(handler, tuple(Outcome(state, when) for state, when in outcomes))


#: the program gives up (``max_attempts`` failures) where it would back off
_GIVE_UP = (S.FAILED, "max_attempts")
_ACCEPTED = _t("on_accepted", (S.RUNNING, ""))
_ACCEPT_LATE = _t("on_accepted", (S.RUNNING, "acceptance lost or reordered"))
_REJECTED = _t("on_rejected", (S.OFFERED, "re-placed at once"), (S.BACKOFF, "turned away again, or closing here"),
               (S.FAILED, "permanent, max_attempts, or deadline unmeetable"))
_HOST_FAILED = _t("on_host_failed", (S.BACKOFF, "host blacklisted"),
                  (S.OFFERED, "host still publishes, or origin cut off: re-placed"), _GIVE_UP)
_RESULT = _t("on_result", (S.DONE, "ok"), (S.FAILED, "program error, or max_attempts"),
             (S.OFFERED, "worker lost: re-placed"), (None, "worker lost, another copy live"),
             (S.BACKOFF, "worker lost, no robot with its accelerator reachable"))
_CANCEL = _t("on_cancel", (S.FAILED, "cancelled"))
_MOVE_FAILED = _t("on_move_failed", (S.RUNNING, "old copy kept"), (S.BACKOFF, "old copy lost meanwhile"), _GIVE_UP)

TRANSITIONS: dict[ProgramState, dict[Event, Transition]] = {
    S.OFFERED: {
        E.ACCEPTED: _ACCEPTED,
        E.REJECTED: _REJECTED,
        E.CONNECT_TIMEOUT: _HOST_FAILED,
        E.HOST_LOST: _HOST_FAILED,
        E.HEARTBEAT: _ACCEPT_LATE,
        E.RESULT: _RESULT,
        E.CANCEL: _CANCEL,
    },
    S.RUNNING: {
        E.HEARTBEAT: _t("on_heartbeat", (None, "")),
        E.HEARTBEAT_TIMEOUT: _HOST_FAILED,
        E.HOST_LOST: _HOST_FAILED,
        E.RESULT: _RESULT,
        E.ACCEPTED: _t("ignore", (None, "duplicate, ignored")),
        E.RELOCATE: _t("relocate", (S.MOVING, "eq. (1) gain over the thresholds")),
        E.CANCEL: _CANCEL,
    },
    S.MOVING: {
        E.ACCEPTED: _t("on_moved", (S.RUNNING, "old copy cancelled")),
        E.HEARTBEAT: _t("on_moved", (S.RUNNING, "acceptance lost or reordered: old copy cancelled")),
        E.REJECTED: _MOVE_FAILED,
        E.CONNECT_TIMEOUT: _MOVE_FAILED,
        E.HOST_LOST: _MOVE_FAILED,
        E.RESULT: _t("on_result", (S.DONE, "ok"), (S.FAILED, "program error"),
                     (S.RUNNING, "new copy's worker lost: old copy kept"),
                     (S.BACKOFF, "new copy's worker lost, old copy gone"), _GIVE_UP),
        E.CANCEL: _CANCEL,
    },
    S.BACKOFF: {
        E.BACKOFF_DONE: _t("place", (S.OFFERED, ""), (S.BACKOFF, "no robot with its accelerator reachable"),
                           (S.FAILED, "deadline unmeetable, on_miss fail; or its accelerator nowhere")),
        E.CANCEL: _CANCEL,
    },
    S.DONE: {},
    S.FAILED: {},
}

FINAL = frozenset({S.DONE, S.FAILED})


class AutonomousProgram:
    """One submitted computation, as its origin tracks it."""

    __slots__ = (
        "program_id", "submit", "state", "attempt", "host", "live", "deadline", "timer",
        "last_heard", "rejections", "excluded", "submitted_at", "failures", "written_off",
        "made", "moves", "moving_from", "accepted_at", "done", "done_at", "work", "checkpoint",
        "checkpoint_fraction", "resumed_from", "move_wanted_since", "ran_on", "placed_at", "stall_base",
        "deaths", "accelerator", "settled", "sending",
    )

    def __init__(self, submit: Submit, now: float) -> None:
        self.program_id = submit.program_id
        self.submit = submit
        self.state = S.OFFERED
        #: number of the current attempt (1 for the first placement)
        self.attempt = 0
        self.host: str | None = None
        #: attempts whose results are still wanted: attempt -> host
        self.live: dict[int, str] = {}
        #: absolute time of the pending timer, and which timer it is
        self.deadline: float | None = None
        self.timer: Event | None = None
        self.last_heard = now
        self.rejections = 0
        self.excluded: set[str] = set()
        self.submitted_at = now
        #: host failures and lost workers so far
        self.failures = 0
        #: attempts written off because their host went silent: (attempt, host, when)
        self.written_off: list[tuple[int, str, float]] = []
        #: attempts made so far (``attempt`` may point back to an older one
        #: when a move is abandoned)
        self.made = 0
        #: relocations started, and the copy still running while one is under
        #: way: [attempt, host, last heard of it]
        self.moves = 0
        self.moving_from: list[Any] | None = None
        #: when the current attempt was accepted (no move before it settles)
        self.accepted_at = now
        #: work units the current attempt has done by the origin's estimate,
        #: as of ``done_at``, and the work it was placed with
        self.done = 0.0
        self.done_at = now
        self.work = submit.work
        #: the latest state the program saved, how far it was then, and the
        #: fraction the current attempt resumed from (None: from the start)
        self.checkpoint: bytes | None = None
        self.checkpoint_fraction = 0.0
        self.resumed_from: float | None = None
        #: since when relocation checks have found a move worth it (None: not now)
        self.move_wanted_since: float | None = None
        #: robots an attempt of this program ran on (accepted it), in order:
        #: relocation never moves it back to one of them
        self.ran_on: dict[str, None] = {}
        #: when the current attempt was offered, and the origin's stalled
        #: seconds then (``Origin.stalled_s``): how long the attempt can have
        #: run at most, stalls of the origin's own clock included
        self.placed_at = now
        self.stall_base = 0.0
        #: the attempt whose offer the driver is still sending whole (0: none): its host
        #: cannot accept before it is through (``ramps.core.silence``)
        self.sending = 0
        #: attempts whose worker the program killed by itself (``ProgramResult.worker_died``):
        #: (attempt, host, how it ended); enough of them make it a poison pill
        self.deaths: list[tuple[int, str, str]] = []
        #: the kind of accelerator the current attempt runs on ("" = a CPU)
        self.accelerator = ""
        #: the attempt that relocation found can no longer move (in a large
        #: view it is not looked at again, ``ramps.core.relocation``); -1: none
        self.settled = -1

    @property
    def placed_host(self) -> str:
        """The current attempt's host: set by the first placement, which
        ``Submit`` makes at once, so every handler may rely on it."""
        if self.host is None:
            raise RuntimeError(f"program {self.program_id}: not placed yet (state {self.state.value!r})")
        return self.host

    def transition(self, event: str) -> Transition:
        """The transition ``event`` takes from the current state, or a
        ``ProtocolError`` naming the program, the state and the event."""
        try:
            return TRANSITIONS[self.state][event if type(event) is Event else Event(event)]
        except (ValueError, KeyError):
            raise ProtocolError(self.program_id, self.state, event) from None

#: a program whose worker died by itself (``ProgramResult.worker_died``: it
#: exited, crashed or was killed while its host lived) on this many different
#: robots, or this many times in all where the team had no other robot for
#: it, is a poison pill: it fails with how each attempt ended instead of
#: being placed again. A host that crashed or shut down under it counts
#: nothing here (that is a host failure, retried up to ``max_attempts``)
POISON_ROBOTS = 2
POISON_DEATHS = 3


def poison_pill(deaths: list[tuple[int, str, str]]) -> bool:
    """Whether a program whose workers died by themselves on these attempts
    ((attempt, host, how)) is a poison pill: on POISON_ROBOTS different
    robots, or POISON_DEATHS times in all."""
    return len({host for _, host, _ in deaths}) >= POISON_ROBOTS or len(deaths) >= POISON_DEATHS


def poison_error(deaths: list[tuple[int, str, str]]) -> str:
    """A poison pill's error: how each attempt's worker ended."""
    robots = len({host for _, host, _ in deaths})
    where = f"on {robots} robots" if robots > 1 else f"{len(deaths)} times on {deaths[0][1]}"
    lines = [f"the program killed its own worker {where}, so it is not placed again (a poison pill):"]
    for attempt, host, how in deaths:
        lines.append(f"  attempt {attempt} on {host}: {how}")
    return "\n".join(lines)


#: a transition handler: an origin's method taking (program, now, out, message, event)
Handler = Callable[..., None]


def resolve_handlers(cls: type, transitions: Mapping[ProgramState, Mapping[Event, Transition]]) -> dict[str, Handler]:
    """Every handler the table names, as ``cls``'s method ``_<name>``; a name
    with no such method is an error naming the state, the event and the name."""
    handlers: dict[str, Handler] = {}
    for state, row in transitions.items():
        for event, transition in row.items():
            method = getattr(cls, "_" + transition.handler, None)
            if not callable(method):
                raise TypeError(f"ramps.core.program.TRANSITIONS[{state.value!r}][{event.value!r}] names handler "
                                f"{transition.handler!r}, but {cls.__name__} has no method _{transition.handler}")
            handlers[transition.handler] = method
    return handlers
