"""The autonomous program: states, and the one table of legal transitions.

How this works: an autonomous program (AP) is created on its origin robot by
``Submit``. It places itself with the origin's policy, offers its parameters
to the chosen host (``OFFERED``), runs there under heartbeat watch
(``RUNNING``), and ends exactly once (``DONE``/``FAILED``) by delivering its
result or a clear error. When its host fails (no acceptance in time, silence,
or the transport reports the host lost) it blacklists the host, waits a
random back-off (``BACKOFF``) and places itself again; when a host turns it
away because it is busier than the origin thought, it re-places at once.

``TRANSITIONS[state][event]`` names the handler (a method of ``Origin``) for
every legal pair. Events about an attempt other than the current one never
reach the table: the origin settles them first (cancel the stray copy, or
discard a stale result). A pair missing from the table is an error that names
the program, state and event: for remote input the origin counts it as an
anomaly and drops it; for local misuse it raises.

    state      event             handler            next
    offered    accepted          on_accepted        running
    offered    rejected          on_rejected        offered | failed
    offered    connect_timeout   on_host_failed     backoff (or offered locally, if cut off)
    offered    host_lost         on_host_failed     backoff
    offered    heartbeat         on_accepted        running  (acceptance lost/reordered)
    offered    result            on_result          done | failed | backoff
    running    heartbeat         on_heartbeat       running
    running    heartbeat_timeout on_host_failed     backoff
    running    host_lost         on_host_failed     backoff
    running    result            on_result          done | failed | backoff
    running    accepted          ignore             running  (duplicate)
    backoff    backoff_done      place              offered
    running    relocate          relocate           moving   (eq. 1 says move)
    moving     accepted          on_moved           running  (old copy cancelled)
    moving     heartbeat         on_moved           running  (acceptance lost/reordered)
    moving     rejected          on_move_failed     running  (old copy kept)
    moving     connect_timeout   on_move_failed     running | backoff (old copy lost meanwhile)
    moving     host_lost         on_move_failed     running | backoff
    moving     result            on_result          done | failed | running
    any live   cancel            on_cancel          failed

Relocation (``MOVING``): the program runs on its old host while a new attempt
is offered to the new one; both attempts are live, so whichever result comes
first is delivered and the other copy cancelled. Once the new host accepts,
the old copy is cancelled; if the new host turns it away or fails, the old
copy simply keeps running.
"""

from __future__ import annotations

from enum import StrEnum
from typing import Any

from ramps.core.events import Submit


class ProgramState(StrEnum):
    OFFERED = "offered"
    RUNNING = "running"
    BACKOFF = "backoff"
    MOVING = "moving"
    DONE = "done"
    FAILED = "failed"


class ProtocolError(Exception):
    """An event that has no transition from the program's current state."""

    def __init__(self, program_id: str, state: ProgramState, event: str) -> None:
        super().__init__(f"program {program_id}: no transition from state {state.value!r} on event {event!r}")
        self.program_id = program_id
        self.state = state
        self.event = event


S = ProgramState
TRANSITIONS: dict[ProgramState, dict[str, str]] = {
    S.OFFERED: {
        "accepted": "on_accepted",
        "rejected": "on_rejected",
        "connect_timeout": "on_host_failed",
        "host_lost": "on_host_failed",
        "heartbeat": "on_accepted",
        "result": "on_result",
        "cancel": "on_cancel",
    },
    S.RUNNING: {
        "heartbeat": "on_heartbeat",
        "heartbeat_timeout": "on_host_failed",
        "host_lost": "on_host_failed",
        "result": "on_result",
        "accepted": "ignore",
        "relocate": "relocate",
        "cancel": "on_cancel",
    },
    S.MOVING: {
        "accepted": "on_moved",
        "heartbeat": "on_moved",
        "rejected": "on_move_failed",
        "connect_timeout": "on_move_failed",
        "host_lost": "on_move_failed",
        "result": "on_result",
        "cancel": "on_cancel",
    },
    S.BACKOFF: {
        "backoff_done": "place",
        "cancel": "on_cancel",
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
        "checkpoint_fraction", "resumed_from", "move_wanted_since",
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
        self.timer: str | None = None
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

    def handler_for(self, event: str) -> str:
        try:
            return TRANSITIONS[self.state][event]
        except KeyError:
            raise ProtocolError(self.program_id, self.state, event) from None
