"""Robots' speeds: measured at boot, re-measured while idle, and corrected
from the results of programs that ran on several robots.

How this works: a node starts from the speed it measured at boot (work
units per second of one of its cores, 1.0 = the reference core): what a CPU
second computes here, timed on the measuring thread's own CPU clock, times
the share of a CPU each core is under the kernel's quota
(``ramps.runtime.speed_probe.measure_speed``). Two corrections, one per side:

- **Re-measurement, on the host** (``SpeedEstimate``): the driver measures
  again while no program runs there, soon after boot and then every
  ``REMEASURE_PERIOD``, on one wall-clock grid for the whole team
  (``next_remeasure``), and hands the core its figure
  from its latest measurements: each the mean over the CPUs of each CPU's
  fastest pieces, timed on a CPU clock, so a quota's throttling and a run
  queue do not count (``ramps.runtime.speed_probe.SpeedSamples``); the trimmed
  mean of the latest measurements outweighs one taken while the neighbours
  kept the machine busy. This is what fixes a robot that measured itself slow:
  it gets no programs, so no result could ever say it is faster. Measured
  on a wall clock instead, a burst that fits in one quota period runs
  faster than the robot's sustained rate.
- **Robots of one hardware class, pooled** (``SpeedClass``): robots that
  report the same class (by default their CPU model) and whose own figures
  differ by no more than their measurements' noise go by the median of the
  class's figures (per CPU second, each scaled by its own quota): a
  second's measurement beside busy processes is noisy (identical robots'
  single measurements differed by up to 1.17x), and a difference the
  measurements cannot tell from noise is not a difference. A robot further
  from the median than ``POOL_Z`` standard errors of its own figures (at
  least ``POOL_MIN``, at most ``POOL_MAX``) keeps its own: a throttled CPU
  stays slow.
- **Results, at the origin** (``HostSpeeds``): a host reports the work a
  program took (``ProgramResult.work_done``): its CPU seconds at the speed
  the host believes (``Executor``), and the origin divides it by the work
  the call declared, so calls of different sizes compare (a call declared
  twice as big counts half). The same program on another robot tells the
  origin what that work is in the team's terms (the median of its recent
  runs elsewhere, each corrected as below): ``elsewhere / work_done`` is
  how much faster (> 1) or slower the host really is than it says. Only
  runs of at least ``MIN_RUN_WORK`` units count (a call of a few
  milliseconds measures its start-up). The origin keeps the median of each
  host's last ``SAMPLES`` figures once it has ``MIN_FIGURES`` of them and
  they are off by more than ``speed_deadband``; its view multiplies the
  host's reported speed by it.
- A run beyond ``speed_max_correction`` either way of another is not a
  robot's speed but a different instance under the same name and
  declaration (a route plan of 4 picks next to one of 14 measured 4-8x
  apart on identical robots): a run is compared only with the runs
  elsewhere within that bound of it, and dropped if there are none. One
  figure alone does not move a factor either: CPU seconds of identical
  robots differ by up to 1.35x with what shares their physical cores at
  the moment (docs/lab/2026-11-26-self-measured-speed.md).

Why the comparison, and not a host comparing a program's estimated work
with the time it took: a program that takes twice as long as declared on
every robot is a program bigger than declared (learned work,
``Origin.work_estimate``), not a team of slow robots; only a robot that is
slower than the others *on the same program* is slow. What this cannot
see: robots that are all wrong by the same factor (harmless: placement
compares them) and a robot that overestimated itself when every run of a
program went to robots as wrong as it (nothing to compare with; a
measurement on a CPU clock is hardly ever too fast).
"""

from __future__ import annotations

import math
from collections import deque
from statistics import median

import msgspec

from ramps.core.config import RampsConfig

#: a host's recent speed figures the origin follows, and a program's recent
#: runs it compares them with
SAMPLES = 5
RUNS = 8
#: figures of a host before its factor may change
MIN_FIGURES = 2
#: the least work (units, about CPU seconds of the reference core) a run
#: must have taken to say anything about its host's speed
MIN_RUN_WORK = 0.1
#: seconds between two re-measurements by the driver once settled (the
#: runtime, and the simulator for robots whose boot measurement was wrong)
REMEASURE_PERIOD = 30.0
#: the first re-measurements after boot come this often, so that a boot
#: measurement taken during the neighbours' start-up is soon outvoted, and
#: for long enough that robots booted seconds apart (a loaded robot's node
#: starts slowly) fill their windows (``SPEED_MEASUREMENTS``) with the same
#: moments of the grid
REMEASURE_EARLY = 3.0
REMEASURE_EARLY_COUNT = 12
#: CPU seconds one re-measurement spends (``measure_speed``'s ``seconds``)
REMEASURE_CPU = 0.2
#: once settled, each re-measurement in a row that did not move the speed
#: doubles the period, up to this many doublings (30 s -> 480 s): at 30 s an
#: idle node's re-measurements alone took 0.67% of a core
REMEASURE_BACKOFF = 4


def next_remeasure(wall: float, count: int, steady: int = 0) -> float:
    """The wall-clock time of a node's next re-measurement after its
    ``count``-th (0: boot), at ``wall`` now: the next multiple of the period
    (``REMEASURE_EARLY`` for the first ``REMEASURE_EARLY_COUNT``, then
    ``REMEASURE_PERIOD``, doubled for each of the ``steady`` latest
    re-measurements in a row that left the speed where it was, at most
    ``REMEASURE_BACKOFF`` times) at least a second away. Every period is a
    multiple of the one before, so robots that backed off measure at moments
    the others measure at too. On one wall-clock grid,
    robots measure at the same moments and so under the same conditions:
    identical robots on one busy host, re-measuring each on its own
    schedule, drifted 1.02-1.22x apart within 20 s as the host's load came
    and went, where their simultaneous boot measurements had agreed
    (docs/lab/2026-11-26-self-measured-speed.md)."""
    period = REMEASURE_EARLY if count < REMEASURE_EARLY_COUNT else \
        REMEASURE_PERIOD * 2 ** min(max(steady, 0), REMEASURE_BACKOFF)
    return math.floor((wall + 1.0) / period + 1.0) * period


#: a re-measured speed within this fraction of the estimate changes nothing
SPEED_STEP = 0.01


def speed_moved(speed: float, before: float) -> bool:
    """``speed`` is a figure and differs from ``before`` by more than ``SPEED_STEP``."""
    return math.isfinite(speed) and speed > 0 and abs(math.log(speed / before)) > math.log1p(SPEED_STEP)


class SpeedMeasured(msgspec.Struct, frozen=True, kw_only=True):
    """The driver measured this robot's speed again (driver -> core), while
    no program ran here: its figure from every measurement so far (on a
    robot, ``ramps.runtime.speed_probe.SpeedSamples``), and that figure's
    relative standard error (0: not known, ``SPEED_NOISE`` is assumed); see
    ``SpeedEstimate.measured``."""

    speed: float
    se: float = 0.0


#: the relative standard error assumed of a figure whose own is not known
#: (a boot measurement alone): single measurements of identical robots
#: beside busy processes differed by 4-17%
SPEED_NOISE = 0.05
#: a robot goes by its class's median when its own figure is within this many
#: standard errors of it (``SpeedClass.rate``), ...
POOL_Z = 3.0
#: ... or within this fraction whatever its error (costs within 5% tie for
#: robots that measure themselves: ``measured_tie_tolerance``), ...
POOL_MIN = 0.05
#: ... and never when further than this: a robot that far off is another machine
POOL_MAX = 0.25


class SpeedClass:
    """What robots of this robot's hardware class measured of a CPU second.

    ``name`` is the class (by default the CPU model, ``speed_class``; empty:
    this robot pools with nobody). Teammates' load reports say their class
    and their own figure per CPU second (``LoadReport.cpu_rate``, before any
    pooling, so figures never feed on each other); ``rate`` gives the figure
    this robot goes by."""

    def __init__(self, name: str = "", robot: str = "") -> None:
        self.name = name
        #: this robot: its own reports, which a node may hear too, are not a teammate's
        self.robot = robot
        #: teammate -> its own work units per CPU second, for those of this class
        self.rates: dict[str, float] = {}

    def heard(self, robot: str, name: str | None, rate: float | None) -> bool:
        """A teammate's report said its class and own figure; True if the
        class's figures changed. A report that names no class (a periodic
        one, or an older node's) says nothing of it."""
        if (name is None and rate is None) or robot == self.robot:
            return False
        if not self.name or name != self.name or rate is None or not (math.isfinite(rate) and rate > 0):
            return self.forget(robot)
        before = self.rates.get(robot)
        self.rates[robot] = rate
        return before != rate

    def forget(self, robot: str) -> bool:
        """A teammate is gone (lost, written off); True if it was of this class."""
        return self.rates.pop(robot, None) is not None

    def rate(self, own: float, se: float) -> tuple[float, int]:
        """(the work units per CPU second this robot goes by, the robots whose
        figures gave it: 1 for its own ``own``, whose relative standard error
        is ``se``): the median of the class, this robot included, when
        ``own`` is within the tolerance of it (``POOL_Z``, ``POOL_MIN``,
        ``POOL_MAX``), figures more than ``POOL_MAX`` off the class's
        median left out; a change of less than ``SPEED_STEP`` moves
        nothing, so robots of one class may go by figures that far apart."""
        if not self.rates or not (math.isfinite(own) and own > 0):
            return own, 1
        figures = [own, *self.rates.values()]
        middle = median(figures)  # then without robots that are other machines (a throttled CPU)
        figures = [f for f in figures if abs(math.log(f / middle)) <= POOL_MAX]
        pooled = median(figures)
        tolerance = min(POOL_MAX, max(POOL_MIN, POOL_Z * (se if se > 0 else SPEED_NOISE)))
        if abs(math.log(own / pooled)) > tolerance:
            return own, 1
        return pooled, len(figures)


class SpeedEstimate:
    """This robot's own speed: the driver's latest figure."""

    def __init__(self, measured: float, config: RampsConfig) -> None:
        self.value = measured
        self.config = config
        #: the relative standard error of ``value`` (``SpeedMeasured.se``; 0: not known)
        self.se = 0.0

    def measured(self, speed: float) -> bool:
        """A re-measurement; True if the estimate changed (by more than
        ``SPEED_STEP``; ``speed_learning = False`` keeps the boot figure).
        Either way: the driver's figure is already robust to interference
        (the trimmed mean of its latest measurements), and a robot that really
        got slower (a throttled CPU) must say so."""
        if not self.config.speed_learning or not speed_moved(speed, self.value):
            return False
        self.value = speed
        return True

    def measured_event(self, event: SpeedMeasured) -> bool:
        """``measured`` for the driver's event, its standard error kept."""
        if self.config.speed_learning and event.se > 0:
            self.se = event.se
        return self.measured(event.speed)


class HostSpeeds:
    """How much faster or slower than reported each host runs programs, as
    one origin sees from their results."""

    def __init__(self, config: RampsConfig) -> None:
        self.config = config
        #: host -> factor on its reported speed (absent = 1)
        self.factor: dict[str, float] = {}
        self._figures: dict[str, deque[float]] = {}
        #: program name -> recent runs: (host, work in the team's terms, when it ended)
        self._runs: dict[str, deque[tuple[str, float, float]]] = {}
        #: results compared, and changes of a factor they made
        self.samples = 0
        self.corrections = 0
        #: host -> the speed its reports said when its figures began
        self._reported: dict[str, float] = {}

    def on_reported_speed(self, host: str, speed: float) -> bool:
        """A load report of ``host`` says it runs at ``speed``; True if that
        moved by more than ``SPEED_STEP`` since its figures began, which are
        then dropped with its factor: they corrected the speed it measured
        before, and its new measurement is the fresher word. (Kept, a factor
        of 0.67 against a boot figure 1.5x too fast went on to scale the
        robot's re-measured true speed down to 0.67 of it, and it got no
        programs.)"""
        if self._reported.get(host) == speed:
            return False  # the common case, without a logarithm: the same figure as before
        if not (math.isfinite(speed) and speed > 0) or not speed_moved(speed, self._reported.setdefault(host, speed)):
            return False
        self._reported[host] = speed
        self._figures.pop(host, None)
        return self.factor.pop(host, None) is not None

    def on_result(self, program: str, host: str, work_done: float, declared: float = 0.0, *,
                  started: float | None = None, now: float = math.inf) -> bool:
        """A first, wanted result of ``program`` from ``host``, which counted
        ``work_done`` units at the speed it reports, of a call that declared
        ``declared`` units (0: compare the raw work), placed at ``started`` and
        ended at ``now``; True if the host's factor changed. It is compared
        only with runs elsewhere still going when it was placed: what a CPU
        second does drifts with the whole team (a host shared with other work,
        a VM at half speed for minutes), and a run against runs of a slower
        minute set one identical robot 1.37x above the rest."""
        cfg = self.config
        if not cfg.speed_learning or not (math.isfinite(work_done) and work_done >= MIN_RUN_WORK):
            return False
        if math.isfinite(declared) and declared > 0:
            work_done /= declared  # per declared unit: calls of different sizes compare
        runs = self._runs.setdefault(program, deque(maxlen=RUNS))
        elsewhere = [w for h, w, end in runs if h != host and (started is None or end >= started)]
        factor = self.factor.get(host, 1.0)
        runs.append((host, work_done * factor, now))
        if not elsewhere:
            return False  # nothing to compare with yet
        # only runs within the bound of this one can be the same instance
        bound = cfg.speed_max_correction
        alike = [w for w in elsewhere if 1.0 / bound <= w / work_done <= bound]
        if not alike:
            return False  # another instance under the same name, not another speed
        figure = median(alike) / work_done
        self.samples += 1
        figures = self._figures.setdefault(host, deque(maxlen=SAMPLES))
        figures.append(figure)
        if len(figures) < MIN_FIGURES:
            return False
        seen = median(figures)
        if abs(math.log(seen / factor)) <= math.log1p(cfg.speed_deadband):
            return False
        self.factor[host] = seen
        self.corrections += 1
        return True
