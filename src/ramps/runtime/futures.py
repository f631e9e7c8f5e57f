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
from typing import Any, Callable

import msgspec

from ramps.core.messages import PROTOCOL_MAJOR, AcceleratorSeen, LearnedWork, LinkSeen, ProgramUpdate, RunningProgram

__all__ = ["ProgramFuture", "RobotStatus", "TeamStatus", "report_about"]


class _ReportAbout(msgspec.Struct, frozen=True):
    type: str = ""
    robot: str = ""


class _ReportHead(msgspec.Struct, frozen=True):
    """A message on the load key, read only as far as the robot its report
    is about (the rest is skipped unparsed)."""

    v: int = 0
    msg: _ReportAbout = _ReportAbout()


_report_head = msgspec.msgpack.Decoder(_ReportHead)
#: what reading a head of garbage raises (``ramps.core.messages.decode`` catches the same)
_NOT_A_REPORT = (msgspec.DecodeError, UnicodeDecodeError, RecursionError)


def report_about(data: bytes) -> str:
    """The robot a load report on the wire is about, reading no further
    (``Team._on_report``); "" if it is no load report of this protocol."""
    try:
        head = _report_head.decode(data)
    except _NOT_A_REPORT:
        return ""
    return head.msg.robot if head.v == PROTOCOL_MAJOR and head.msg.type == "load" else ""


class RobotStatus(msgspec.Struct, frozen=True, kw_only=True):
    """One robot as a client sees it (``Team.status()``): ``alive`` and
    ``leaving`` from its liveliness tokens, the rest from its latest load
    report (defaults where none arrived yet), which is ``report_age``
    seconds old."""

    robot: str
    alive: bool
    #: its node said it is leaving (stopped: Ctrl-C, SIGTERM, revoked; it
    #: hands its programs back), so not alive any more means it left, not crashed
    leaving: bool = False
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
    #: its accelerators: [kind, slots, speed, programs on them, memory total, free, utilisation]
    accelerators: list[AcceleratorSeen] = []
    #: its battery's state of charge, 0..1 (None: it reports none); below its reserve
    #: (``low_battery``) it takes no teammates' programs; watts a busy core draws
    battery: float | None = None
    low_battery: bool = False
    power: float | None = None


class TeamStatus(msgspec.Struct, frozen=True, kw_only=True):
    """The team as a client sees it (``Team.status()``): its robots by name."""

    team: str
    robots: list[RobotStatus]


class ProgramFuture(Future):
    """A ``concurrent.futures.Future`` that follows its program on the team.

    ``program``: its name; ``state``: "submitted", "placed", "running",
    "replaced" (placed again after a failure or refusal), "host_failed",
    then how it ended: "done" (a result), "failed" (an error: the program
    raised, was refused or lost), "timed_out" (its per-call timeout withdrew
    it) or "cancelled" (``cancel()`` withdrew it); ``host``: the robot it was
    last offered to (the one that ran it, once done); ``attempts``:
    placements so far, the first included (a re-placement after a host
    failed or handed it back is one more); ``progress``: the newest fraction
    (0..1) the program reported, or None; ``progress_detail``: the text that
    came with it; once done, ``moves``: how often the origin relocated it
    while it ran on a healthy host (to a robot where it finishes sooner, see
    "Programs that move" in docs/using-ramps.md; a re-placement after a
    failure is not a move, it shows in ``attempts``), and ``resumed_from``:
    the progress of the checkpoint its last attempt resumed from (None: it
    ran from the start, see ``ramps.checkpoint``), and ``missed_deadline``:
    it had a deadline (``team.options(deadline=...)``) and its result came
    after it. Updates are advisory
    (they may be lost or arrive late); the result, and the state it sets,
    are not."""

    def __init__(self, program: str = "") -> None:
        super().__init__()
        self.program = program
        #: the newest update's state, while the program runs (``state``)
        self._state = "submitted"
        self.host = ""
        self.attempts = 0
        self.progress: float | None = None
        self.progress_detail = ""
        self.moves = 0
        self.resumed_from: float | None = None
        self.missed_deadline = False
        self._update_callbacks: list[Callable[[Future[Any]], object]] = []

    def add_update_callback(self, fn: Callable[[Future[Any]], object]) -> None:
        """Call ``fn(future)`` (on a ramps thread: do not block) whenever the
        state, host or progress changes, and once when the future is done."""
        self._update_callbacks.append(fn)
        self.add_done_callback(fn)

    @property
    def state(self) -> str:
        """Where the program stands (see the class's docstring): once the
        future is done, how it ended, read from the future itself, so it
        can never disagree with ``result()``; before that, the newest
        update's state."""
        if not self.done():
            return self._state
        if self.cancelled():  # done is final: these no longer change
            return "cancelled"
        exc = self.exception(timeout=0)
        if exc is None:
            return "done"
        return "timed_out" if isinstance(exc, TimeoutError) else "failed"

    def _updated(self, u: ProgramUpdate) -> None:
        if self.done():
            return
        if u.state != "progress":
            self._state = u.state
        elif self._state in ("submitted", "placed", "replaced"):
            self._state = "running"  # progress comes from a running program
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
