"""What a node measures of its robot: cores, speed, where load is read, its own CPU.

How this works: ``RobotMeasure`` is a part of the node's driver
(``ramps.runtime.node``). At start (``measure``) it finds the robot's
cores (``--cores``, else the host's), its CPU quota (the smallest on its
cgroup's path), where load is measured (``--load-scope``: the cgroup when
there is a quota) and its speed (``--speed``, else measured, pieces kept in
``SpeedSamples``). A speed measured at boot is measured again while no
program runs, soon after boot and then now and then (less often while it
finds the same speed), on a grid of wall-clock moments the whole team
shares (robots booting together measure each other's start-up;
``ramps.core.speed``): before each periodic report the driver
asks ``remeasure_due``, which starts the measurement's thread a little
early; its figure goes to the driver's queue as a ``("speed", ...)`` item.
For each report it also scales a cgroup's CPU use to the robot's cores
(``busy``) and averages the node's own CPU (``read_node_cpu``).
"""

from __future__ import annotations

import logging
import os
import threading
import time
from pathlib import Path
from typing import Any, Callable

import msgspec

from ramps.core.config import RampsConfig
from ramps.core.speed import REMEASURE_CPU, REMEASURE_EARLY_COUNT, SpeedMeasured, next_remeasure, speed_moved
from ramps.runtime.measure import cgroup_dirs, cpu_limit, cpu_model, detect_cores
from ramps.runtime.settings import NodeSettings
from ramps.runtime.speed_probe import Interrupted, SpeedSamples, core_fraction, measure_speed
from ramps.runtime.transport import Clock

log = logging.getLogger("ramps.node")
#: how long before its moment a re-measurement's thread starts (more than a report period)
REMEASURE_LEAD = 1.5
#: weight of the latest report period in the node's averaged own CPU (about 10 reports)
NODE_CPU_ALPHA = 0.1


def core_config(s: NodeSettings) -> RampsConfig:
    """The core's settings for a node of ``s``: on a node that measures its own
    speed (no ``speed`` given), costs tie within ``measured_tie_tolerance``,
    the noise of identical robots' self-measured speeds."""
    core = s.core
    if not s.speed and core.measured_tie_tolerance > core.tie_tolerance:
        core = msgspec.structs.replace(core, tie_tolerance=core.measured_tie_tolerance)
    return core


class RobotMeasure:
    """The measures of robot ``robot`` (settings ``s``), taken at ``measure``."""

    def __init__(self, s: NodeSettings, clock: Clock, robot: str) -> None:
        self.s = s
        self.clock = clock
        self.robot = robot
        self.cores = 0
        self.speed = 0.0
        #: the CPU quota, in cores (None: none), and where load is measured: "cgroup" or "host"
        self.quota: float | None = None
        self.scope = s.load_scope
        self.cgroup: Path | None = None
        self.acct: Path | None = None
        self.samples = SpeedSamples()
        #: a cgroup's CPU use is in host cores; a robot of ``cores`` emulated at a
        #: smaller quota reports it in its own cores, as its speed is scaled
        self.busy_scale = 1.0
        #: the wall-clock time of the next re-measurement (None: told its speed), how many were due
        self.remeasure_at: float | None = None
        self.remeasures = 0
        #: re-measurements in a row that left the speed where it was (the period backs off)
        self.steady = 0
        self._remeasuring = threading.Lock()
        #: this process's CPU seconds and the time when last read, and the cores it used
        #: (averaged), for load reports: the cost model takes them off a full robot's cores
        self._node_cpu_at: tuple[float, float] | None = None
        self.node_cpu = 0.0

    def measure(self) -> None:
        """Cores, quota, where load is measured, speed (at start: measuring takes about a second)."""
        s = self.s
        self.cgroup, self.acct = cgroup_dirs()
        self.quota = quota = cpu_limit(self.cgroup)
        if self.scope == "auto":
            self.scope = "cgroup" if quota is not None else "host"
        self.cores = s.cores or detect_cores()
        self.speed = s.speed or measure_speed(quota=quota, cores=self.cores, samples=self.samples, boot=True)
        self.remeasure_at = None if s.speed else next_remeasure(self.clock.time(), 0)
        self.busy_scale = (self.cores / quota if self.scope == "cgroup" and quota is not None and quota < self.cores
                           else 1.0)

    def core_fraction(self) -> float:
        """The share of its cores the robot may use (its quota over its cores)."""
        return core_fraction(self.quota, self.cores)

    def speed_class(self) -> str:
        """The robot's hardware class for the core: none when told its speed."""
        s = self.s
        return "" if s.speed else cpu_model() if s.speed_class == "auto" else s.speed_class

    def busy(self, busy: float) -> float:
        """CPU use as the sampler read it, in the robot's cores."""
        return min(busy * self.busy_scale, float(self.cores)) if self.scope == "cgroup" else busy

    def remeasure_due(self, idle: Callable[[], bool], put: Callable[[tuple[Any, ...]], None]) -> None:
        """Before a periodic report: start the next re-measurement if its
        moment is near. Its thread starts up to REMEASURE_LEAD early and waits
        for the grid's moment, so every robot measures then, whatever the
        phase of its reports; a moment missed (a program ran, a stall) is
        skipped for the next on the grid."""
        due = self.remeasure_at
        wall = self.clock.time()
        if due is None or wall < due - REMEASURE_LEAD:
            return
        if due > wall - 0.5 and idle():
            threading.Thread(target=self._remeasure, args=(due, idle, put), name=f"ramps-speed-{self.robot}",
                             daemon=True).start()
        self.remeasures += 1
        self.remeasure_at = next_remeasure(due, self.remeasures, self.steady)

    def _remeasure(self, at: float, idle: Callable[[], bool], put: Callable[[tuple[Any, ...]], None]) -> None:
        """Measure this robot's speed again at wall-clock time ``at`` (the
        team's grid, ``next_remeasure``), off the driver's thread (briefly:
        ``REMEASURE_CPU`` s of CPU), with every piece timed so far
        (``SpeedSamples``), unless a program started meanwhile (before or
        while it measures: the measuring child is killed); the core
        takes the figure if it moved. A measurement still running when the
        next one's thread starts (one beside busy processes takes longer than
        its second) is waited for until the moment: a moment one robot skips
        and its teammates measure sets their figures apart."""
        if not self._remeasuring.acquire(timeout=max(0.0, at + 0.5 - self.clock.time())):
            return
        try:
            self.clock.sleep(max(0.0, at - self.clock.time()))
            if not idle():
                return
            before = self.samples.speed(quota=self.quota, cores=self.cores)
            speed = measure_speed(REMEASURE_CPU, quota=self.quota, cores=self.cores, samples=self.samples,
                                  apart=True, stop=lambda: not idle())
            figure = self.samples.latest * self.core_fraction()
            settled = self.remeasures > REMEASURE_EARLY_COUNT  # the boot's early moments never back off
            self.steady = 0 if speed_moved(speed, before) else self.steady + 1 if settled else 0
        except Interrupted:  # a program started: it has the robot's CPU, the next moment on the grid measures
            return
        except Exception:  # never worth a node
            log.exception("node %s: measuring its speed again failed", self.robot)
            return
        finally:
            self._remeasuring.release()
        put(("speed", SpeedMeasured(speed=speed, se=self.samples.se()), at, figure))

    def read_node_cpu(self) -> float:
        """The cores this node's own process used since the last report (its threads:
        Zenoh, the driver, the sampler; programs run in other processes), in the robot's
        cores, averaged over about ``1 / NODE_CPU_ALPHA`` reports. Real CPU seconds over
        real seconds, whatever clock drives the node."""
        t = os.times()
        used, wall = t.user + t.system, time.monotonic()
        last, self._node_cpu_at = self._node_cpu_at, (used, wall)
        if last is not None and wall - last[1] >= 0.05:
            rate = min(float(self.cores), max(0.0, used - last[0]) / (wall - last[1]) * self.busy_scale)
            self.node_cpu += NODE_CPU_ALPHA * (rate - self.node_cpu)
        return self.node_cpu
