"""What a client holds while its programs run on the team: futures and the team's status.

How this works: ``ramps.connect()`` (``ramps.runtime.client``) returns a
``Team`` whose ``submit`` gives a ``ProgramFuture``: a
``concurrent.futures.Future`` that ``settle`` resolves with the one
``ProgramOutcome`` of its program (its value, or the error of the
``ramps.errors`` tree its ``error_kind`` names), and that is updated (state,
host, attempts, progress) with each advisory ``ProgramUpdate`` on the way.
``Team.status()`` answers with a ``TeamStatus``: one ``RobotStatus`` per
robot, from its liveliness and its newest load report, which
``TeamReports`` keeps as it came and decodes only when asked.
"""

from __future__ import annotations

from concurrent.futures import Future
from typing import Any, Callable

import msgspec

from ramps.core.messages import (
    PROTOCOL_MAJOR,
    AcceleratorSeen,
    LearnedWork,
    LinkSeen,
    LoadReport,
    ProgramOutcome,
    ProgramUpdate,
    RunningProgram,
    WireError,
    decode,
)
from ramps.errors import BadArguments, DeadlineUnmeetable, ProgramFailed, ProgramLost, ProgramRefused
from ramps.runtime.registry import decode_value

__all__ = ["ProgramFuture", "RobotStatus", "TeamReports", "TeamStatus", "report_about", "settle"]


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


class TeamReports:
    """Each robot's newest periodic load report as a client keeps it (reports
    of the instant go to nodes only): as it came, read only as far as the
    robot it is about (``report_about``); ``status`` decodes the newest of
    each robot, so a client that never asks decodes none. A newest report
    that turns out malformed leaves the one decoded before. A report lists a
    few of its robot's links in turn: the row lists the newest of each. Not thread-safe:
    the Team's lock guards it."""

    def __init__(self) -> None:
        #: each robot's newest report as it came, not decoded yet, and when it came
        self.raw: dict[str, tuple[bytes, float]] = {}
        self.decoded: dict[str, tuple[LoadReport, float]] = {}
        #: each robot's links as its reports listed them, the newest of each
        #: teammate (a report lists a few in turn), and the incarnation they are of
        self.links: dict[str, tuple[int, dict[str, LinkSeen]]] = {}

    def keep(self, robot: str, data: bytes, at: float) -> None:
        """A report about ``robot`` came at ``at`` (``report_about(data)``)."""
        self.raw[robot] = (data, at)

    def status(self, team: str, alive: set[str], leaving: set[str], now: float) -> TeamStatus:
        """The team at ``now``: every robot alive or reported, by name."""
        raw, self.raw = self.raw, {}
        for robot, (data, at) in raw.items():
            try:
                env = decode(data)
            except WireError:
                continue
            if isinstance(env.msg, LoadReport) and env.msg.robot == robot:
                self.decoded[robot] = (env.msg, at)
                inc, seen = self.links.get(robot, (env.msg.incarnation, {}))
                if inc != env.msg.incarnation:  # restarted: what it measured before is gone
                    seen = {}
                seen.update((link.robot, link) for link in env.msg.links)
                self.links[robot] = (env.msg.incarnation, seen)
        rows = []
        for name in sorted(alive | set(self.decoded)):
            got = self.decoded.get(name)
            base: dict[str, Any] = dict(robot=name, alive=name in alive, leaving=name in leaving)
            if got is not None:
                rep, at = got
                base.update(cores=rep.cores, speed=rep.speed, cpu_busy=rep.cpu_busy, runnable=rep.runnable,
                            ramps_running=rep.ramps_running, accepted_total=rep.accepted_total,
                            finished_total=rep.finished_total, blacklisted=list(rep.blacklisted),
                            cpu_per_core=list(rep.cpu_per_core), load_avg=rep.load_avg,
                            mem_free=rep.mem_free, bad_messages=rep.bad_messages, report_age=now - at,
                            sees=rep.sees, running=list(rep.running), links=self._links(name, alive),
                            learned=list(rep.learned), moves=rep.moves, moves_aborted=rep.moves_aborted,
                            node_cpu=rep.node_cpu, accelerators=list(rep.accelerators), battery=rep.battery,
                            low_battery=rep.low_battery, power=rep.power)
            rows.append(RobotStatus(**base))
        return TeamStatus(team=team, robots=rows)

    def _links(self, robot: str, alive: set[str]) -> list[LinkSeen]:
        """``robot``'s newest link to each teammate still alive or reported, by name."""
        _, seen = self.links.get(robot, (0, {}))
        return [seen[r] for r in sorted(seen) if r in alive or r in self.decoded]


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


#: the error each ``ProgramOutcome.error_kind`` raises (any other: ``ProgramLost``)
_ERRORS = {"program": ProgramFailed, "refused": ProgramRefused, "bad_arguments": BadArguments,
           "deadline": DeadlineUnmeetable}


def settle(fut: ProgramFuture, o: ProgramOutcome, sender: str) -> None:
    """Resolve ``fut`` with its program's outcome (``sender``: the node that
    sent it): its value, or its error; a result this client cannot read is
    an error, never a hang. One cancelled meanwhile stays so."""
    fut.host = o.host  # which robot ran it
    fut.attempts = o.attempts
    fut.moves, fut.resumed_from = o.moves, o.resumed_from
    fut.missed_deadline = o.missed_deadline
    try:
        if o.ok:
            try:
                value = decode_value(o.value)
            except Exception as exc:
                fut.set_exception(ProgramFailed(f"{fut.program} on {o.host or sender}: its result could not "
                                                f"be decoded ({type(exc).__name__}: {exc})", host=o.host,
                                                attempts=o.attempts))
                return
            fut.set_result(value)
        else:
            cls = _ERRORS.get(o.error_kind, ProgramLost)
            if cls is BadArguments:
                fut.set_exception(BadArguments(o.error))
            else:
                fut.set_exception(cls(f"{fut.program} on {o.host or sender}: {o.error}", host=o.host,
                                      attempts=o.attempts))
    except Exception:  # the future was cancelled meanwhile
        pass
