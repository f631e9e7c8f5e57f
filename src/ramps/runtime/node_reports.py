"""A node's load reports: the periodic one, and those of the instant.

How this works: ``LoadReports`` is a part of the node's driver
(``ramps.runtime.node``), given the parts it reads and publishes through;
of the driver it reads only what ``ReportsDriver`` names, what the driver
has once started (the core, its pool, sampler, accelerators and metrics).
Every report period the driver calls ``publish``: it starts a
re-measurement of the robot's speed when one is due (``RobotMeasure``),
reads the sampler, the robot's battery (``ramps.runtime.battery``, handed
to the core: below its reserve it hands back its teammates' programs) and
the accelerators, has the core make the report, adds what only a person
reads (what runs here, the links and learned work, ``ramps status``'s
counters) and publishes it on ``keys.load``, the report applications hear.
In a team of more teammates than ``RampsConfig.report_rate``, a periodic
report goes on the wire every ``RampsConfig.report_period`` instead (up to
3 s), so that an origin of a large team hears a bounded number a second,
and at the next publish when it differs in what a teammate decides on
(``ramps.core.cadence``).
The links go ``LINKS_PER_REPORT`` teammates a report, in turn, so a
report's size does not grow with the team; a client keeps the newest of
each (``ramps.runtime.futures.TeamReports``).
A report of the instant (``PublishReport``: the programs running here
changed) goes to the teammates' nodes only (``keys.load_now``), at once
(``publish_prompt``). The core holds them (``Node.prompt_hold``, set by the
driver to ``PROMPT_HOLD``) so that the changes that follow one go with it:
it makes one report when the hold is over, with the executor's newest
counters, instead of one per change. The newest
report published, of either kind, is what this robot answers a teammate's query with (``Membership.newest``:
an origin's first views). A robot that places programs reports as those it
sees the teammates it could place on (fresh reports, not written off); one
that does not hears no periodic reports, and reports those whose
liveliness it holds.
"""

from __future__ import annotations

import logging
import math
from itertools import islice
from typing import TYPE_CHECKING, Any, Callable, Protocol

import msgspec

from ramps.core.battery import BatteryMeasured
from ramps.core.cadence import ReportCadence
from ramps.core.events import Action
from ramps.core.links import in_turn
from ramps.core.messages import MAX_LISTED, LearnedWork, LinkSeen, LoadReport, RunningProgram, encode
from ramps.runtime.battery import BatteryReader

if TYPE_CHECKING:
    from ramps.core.node import Node
    from ramps.runtime.accelerators import AcceleratorProbe
    from ramps.runtime.metrics import NodeMetrics
    from ramps.runtime.node_awake import AwakeClock
    from ramps.runtime.node_intake import WireIntake
    from ramps.runtime.node_robot import RobotMeasure
    from ramps.runtime.node_seams import SamplerLike, WorkerPoolLike
    from ramps.runtime.node_team import Membership
    from ramps.runtime.node_trace import NodeTrace
    from ramps.runtime.settings import NodeSettings

log = logging.getLogger("ramps.node")
#: seconds the core holds a report of the instant for the changes that follow it (``Node.prompt_hold``),
#: the newest going then: a host's acceptance and the end of a short program go as one report, after
#: its result, and the teammates it wakes do not take the CPU from the program meanwhile
PROMPT_HOLD = 0.005


class ReportsDriver(Protocol):
    """What a node's load reports (``LoadReports``) read of its driver: what
    the driver has once started."""

    node: Node | None
    pool: WorkerPoolLike
    sampler: SamplerLike
    accel: AcceleratorProbe
    metrics: NodeMetrics | None


#: teammates whose measured links one periodic report lists (the next ones in the next report)
LINKS_PER_REPORT = 8


class LoadReports:
    """The load reports of ``driver``'s node, of settings ``s``, which
    ``apply`` the core's actions and queue the driver's items with ``put``."""

    def __init__(self, driver: ReportsDriver, s: NodeSettings, *, apply: Callable[[list[Action]], None],
                 put: Callable[[tuple[Any, ...]], None], awake: AwakeClock, measured: RobotMeasure,
                 membership: Membership, trace: NodeTrace, intake: WireIntake) -> None:
        self.d = driver
        self.s, self.robot = s, s.robot
        self._apply, self._put = apply, put
        self.awake, self.measured, self.membership, self.trace = awake, measured, membership, trace
        #: messages dropped as bad input and over the driver's backlog (``ramps status``)
        self.intake = intake
        #: the last periodic report, and the teammates in this robot's view then
        self.last: LoadReport | None = None
        self._sees: frozenset[str] = frozenset()
        #: reads this robot's battery before each periodic report (made at the first)
        self._battery: BatteryReader | None = None
        #: where the next report's links start in the sorted teammates measured
        self._links_turn = 0
        #: the last periodic report that went on the wire, and when
        self.cadence = ReportCadence()

    def publish(self, now: float) -> None:
        """The periodic load report, at the core's time ``now``."""
        d = self.d
        self.measured.remeasure_due(lambda: not d.pool.busy() and not d.pool.queued(), self._put)
        node = d.node
        assert node is not None
        busy, runnable, ramps_avg = d.sampler.averages()
        per_core, load1, mem_free = d.sampler.extras()
        node.executor.background = max(0.0, runnable - ramps_avg)
        busy = self.measured.busy(busy)
        node_cpu = self.measured.read_node_cpu()
        self._read_battery(now, busy)
        if d.accel.declared:
            node.accelerator_measured = d.accel.measure()
        report = node.make_report(cpu_busy=busy, runnable=runnable, ramps_avg=ramps_avg, window=self.s.window,
                                  mem_free=mem_free, cpu_per_core=per_core, load_avg=load1,
                                  node_cpu=round(node_cpu, 4))
        m = self.membership
        sees = frozenset(node.view.candidates(now) if m.wide else m.alive) - {self.robot}
        if sees != self._sees:
            self._log_view_change(self._sees, sees)
            self._sees = sees
        report = msgspec.structs.replace(report, bad_messages=self.intake.bad + self.intake.overflow,  # `ramps status`
                                         sees=len(sees), running=self._running_list(), **self._learned())
        self.last = report
        if d.metrics is not None:
            st = node.statistics()
            d.metrics.on_report(cpu_busy=busy, runnable=runnable, load_avg=load1, mem_free=mem_free,
                                running=st.running, in_flight=st.active_programs, sees=len(sees),
                                blacklisted=len(st.blacklisted), dropped=report.bad_messages,
                                reports_received=st.reports_received)
        try:
            m.newest = data = encode(self.robot, report)  # a teammate's query gets it, due or not
            period = node.config.report_period(self.s.publish_period, len(m.alive))
            if self.cadence.due(report, now, period, self.s.publish_period):
                m.load_pub.put(data)
                if self.trace.wire:
                    self.trace.write("tx", "", "*", 0, "LoadReport")
        except Exception as exc:
            log.warning("node %s could not publish its load: %s", self.robot, exc)

    def _read_battery(self, now: float, busy: float) -> None:
        """Hand the core this robot's battery (``ramps.core.battery``): below
        its reserve it hands back its teammates' programs, in this report period."""
        if self._battery is None:
            self._battery = BatteryReader.for_settings(self.s)
        charge, power = self._battery.read(busy)
        assert self.d.node is not None
        self._apply(self.d.node.handle(BatteryMeasured(charge=charge, power=power), now))

    def publish_prompt(self, report: LoadReport) -> None:
        """A report of the instant from the core (its programs changed), to its
        teammates' nodes only (``keys.load_now``), as the core made it: what
        their decisions read. What only a person reads (what runs here, the
        links, ``ramps status``'s counters) goes with the periodic report,
        the one applications hear: a client busy submitting hears no report
        per program start and end."""
        try:
            self.membership.newest = data = encode(self.robot, report)
            self.membership.prompt_pub.put(data)
        except Exception as exc:
            log.warning("node %s could not publish its load: %s", self.robot, exc)

    def _learned(self) -> dict[str, list[Any]]:
        """What this node measured of its links and learned of its programs'
        work, for its load report (``ramps status``)."""
        def ok(x: float | None) -> float | None:  # within the schema, or the whole report would be refused
            return x if x is not None and math.isfinite(x) and x >= 0 else None

        node = self.d.node
        assert node is not None
        measured = node.links.measured()
        factors = node.host_speeds.factor if node.host_speeds is not None else {}
        # teammates only: an origin also compares the runs on its own robot
        known = sorted((set(measured) | set(factors)) - {self.robot})
        if len(known) > LINKS_PER_REPORT:  # the next few in turn
            known, self._links_turn = in_turn(known, self._links_turn, LINKS_PER_REPORT)
        links = [(r, measured.get(r)) for r in known]
        work = sorted(node.origin.learned_work().items())[:MAX_LISTED]
        return dict(links=[LinkSeen(r, ok(e.latency) if e else None, ok(e.bandwidth) if e else None,
                                    ok(factors.get(r))) for r, e in links],
                    learned=[LearnedWork(p, w) for p, w in work if ok(w) is not None])

    def _running_list(self) -> list[RunningProgram]:
        """The programs this robot runs, with their progress (``ramps status``)."""
        assert self.d.node is not None
        jobs = islice(self.d.node.executor.running.values(), MAX_LISTED)
        return [RunningProgram(j.program, j.origin, j.progress) for j in jobs]

    def _log_view_change(self, before: frozenset[str], after: frozenset[str]) -> None:
        """One line when teammates enter or leave this robot's view (the
        robots it could place programs on), so a log tells who it saw when."""
        def names(robots: frozenset[str]) -> str:
            shown = sorted(robots)
            return ", ".join(shown[:8]) + (f" and {len(shown) - 8} more" if len(shown) > 8 else "")

        parts = [f"+{names(after - before)}" if after - before else "",
                 f"-{names(before - after)}" if before - after else ""]
        log.info("node %s sees %d teammate(s): %s", self.robot, len(after), " ".join(p for p in parts if p))
