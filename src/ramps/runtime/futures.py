"""What a client holds while its programs run on the team: futures and the team's status.

How this works: ``ramps.connect()`` (``ramps.runtime.client``) returns a
``Team`` whose ``submit`` gives a ``ProgramFuture``: a
``concurrent.futures.Future`` that the client's callbacks resolve with the
one ``ProgramOutcome`` of its program, and update (state, host, attempts,
progress) with each advisory ``ProgramUpdate`` on the way.
``Team.status()`` answers with a ``TeamStatus``: one ``RobotStatus`` per
robot, from its latest load report and liveliness.
"""

from __future__ import annotations

from concurrent.futures import Future

import msgspec

from ramps.core.messages import LearnedWork, LinkSeen, ProgramUpdate, RunningProgram

__all__ = ["ProgramFuture", "RobotStatus", "TeamStatus"]


class RobotStatus(msgspec.Struct, frozen=True, kw_only=True):
    """One robot as a client sees it (``Team.status()``): ``alive`` from its
    liveliness token, the rest from its latest load report (defaults where
    none arrived yet), which is ``report_age`` seconds old."""

    robot: str
    alive: bool
    cores: int = 0
    speed: float = 0.0
    cpu_busy: float = 0.0
    runnable: float = 0.0
    ramps_running: int = 0
    #: messages the robot's node dropped (undecodable, or over its backlog)
    bad_messages: int = 0
    accepted_total: int = 0
    finished_total: int = 0
    blacklisted: list[str] = []
    cpu_per_core: list[float] = []
    load_avg: float = 0.0
    mem_free: int = 0
    report_age: float | None = None
    #: teammates the robot could place a program on (None: not reported)
    sees: int | None = None
    #: programs running there: [program, origin robot, progress 0..1 or None]
    running: list[RunningProgram] = []
    #: the robot's measured links to teammates [teammate, latency s, bandwidth B/s],
    #: and the work it learned of the programs it placed [program, work units]
    links: list[LinkSeen] = []
    learned: list[LearnedWork] = []
    #: the robot's programs moved while running since its node started, and moves abandoned
    moves: int = 0
    moves_aborted: int = 0
    #: cores the robot's node itself uses (the cost model takes them off a full robot's)
    node_cpu: float = 0.0


class TeamStatus(msgspec.Struct, frozen=True, kw_only=True):
    """The team as a client sees it (``Team.status()``): its robots by name."""

    team: str
    robots: list[RobotStatus]


class ProgramFuture(Future):
    """A ``concurrent.futures.Future`` that follows its program on the team.

    ``program``: its name; ``state``: "submitted", "placed", "running",
    "replaced" (placed again after a failure or refusal), "host_failed",
    then "done" or "failed"; ``host``: the robot it was last offered to (the
    one that ran it, once done); ``attempts``: placements so far;
    ``progress``: the newest fraction (0..1) the program reported, or None;
    ``progress_detail``: the text that came with it; once done, ``moves``:
    how often it was relocated while running, and ``resumed_from``: the
    progress of the checkpoint its last attempt resumed from (None: it ran
    from the start, see ``ramps.checkpoint``). Updates are advisory
    (they may be lost or arrive late); the result is not."""

    def __init__(self, program: str = "") -> None:
        super().__init__()
        self.program = program
        self.state = "submitted"
        self.host = ""
        self.attempts = 0
        self.progress: float | None = None
        self.progress_detail = ""
        self.moves = 0
        self.resumed_from: float | None = None
        self._update_callbacks: list = []

    def add_update_callback(self, fn) -> None:
        """Call ``fn(future)`` (on a ramps thread: do not block) whenever the
        state, host or progress changes, and once when the future is done."""
        self._update_callbacks.append(fn)
        self.add_done_callback(fn)

    def _updated(self, u: ProgramUpdate) -> None:
        if self.done():
            return
        if u.state != "progress":
            self.state = u.state
        elif self.state in ("submitted", "placed", "replaced"):
            self.state = "running"  # progress comes from a running program
        if u.host:
            self.host = u.host
        self.attempts = max(self.attempts, u.attempt)
        if u.fraction is not None:
            self.progress, self.progress_detail = u.fraction, u.detail
        for fn in list(self._update_callbacks):
            try:
                fn(self)
            except Exception:  # a callback's bug must not stop the others (Future does the same)
                pass
