"""Robots' speeds: re-measured while idle, and corrected from the results
of programs that ran on several robots.

How this works: a node starts from the speed it measured at boot (work
units per second of one core, 1.0 = the reference core). Robots booting
together on a busy machine measured speeds up to 1.5x apart for identical
hardware, and placement followed the error. Two corrections, one per side:

- **Re-measurement, on the host** (``SpeedEstimate``): the driver measures
  again now and then while no program runs there (``REMEASURE_PERIOD``).
  Interference (other processes, a busy machine) only ever slows a
  measurement down, so the fastest one is the robot's own speed: a faster
  re-measurement replaces the estimate, a slower one is ignored. This is
  what fixes a robot that measured itself slow: it gets no programs, so no
  result could ever say it is faster.
- **Results, at the origin** (``HostSpeeds``): a host reports the work a
  program took (``ProgramResult.work_done``) counted at the speed it
  believes. The same program on another robot tells the origin what that
  work is in the team's terms (the median of its recent runs elsewhere,
  each corrected as below): ``elsewhere / work_done`` is how much faster
  (> 1) or slower the host really is than it says. The origin keeps the
  median of each host's last ``SAMPLES`` such figures once it is off by more
  than ``speed_deadband``, within ``speed_max_correction`` either way, and
  its view multiplies the host's reported speed by it.

Why the comparison, and not a host comparing a program's estimated work
with the time it took: a program that takes twice as long as declared on
every robot is a program bigger than declared (learned work,
``Origin.work_estimate``), not a team of slow robots; only a robot that is
slower than the others *on the same program* is slow. What this cannot
see: robots that are all wrong by the same factor (harmless: placement
compares them) and a robot that overestimated itself when every run of a
program went to robots as wrong as it (nothing to compare with; a
measurement is hardly ever too fast).
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
#: seconds between two re-measurements by the driver (the runtime, and the
#: simulator for robots whose boot measurement was wrong)
REMEASURE_PERIOD = 30.0


class SpeedMeasured(msgspec.Struct, frozen=True, kw_only=True):
    """The driver measured this robot's speed again (driver -> core), while
    no program ran here; see ``SpeedEstimate.measured``."""

    speed: float


class SpeedEstimate:
    """This robot's own speed: the fastest measurement so far."""

    def __init__(self, measured: float, config: RampsConfig) -> None:
        self.value = measured
        self.config = config

    def measured(self, speed: float) -> bool:
        """A re-measurement; True if the estimate changed (only a faster one
        counts; ``speed_learning = False`` keeps the boot figure)."""
        if not self.config.speed_learning or not (math.isfinite(speed) and speed > self.value):
            return False
        self.value = speed
        return True


class HostSpeeds:
    """How much faster or slower than reported each host runs programs, as
    one origin sees from their results."""

    def __init__(self, config: RampsConfig) -> None:
        self.config = config
        #: host -> factor on its reported speed (absent = 1)
        self.factor: dict[str, float] = {}
        self._figures: dict[str, deque[float]] = {}
        #: program name -> recent runs: (host, work in the team's terms)
        self._runs: dict[str, deque[tuple[str, float]]] = {}
        #: results compared, and changes of a factor they made
        self.samples = 0
        self.corrections = 0

    def on_result(self, program: str, host: str, work_done: float) -> bool:
        """A first, wanted result of ``program`` from ``host``, which counted
        ``work_done`` units at the speed it reports; True if the host's
        factor changed."""
        cfg = self.config
        if not cfg.speed_learning or not (math.isfinite(work_done) and work_done > 0):
            return False
        runs = self._runs.setdefault(program, deque(maxlen=RUNS))
        elsewhere = [w for h, w in runs if h != host]
        factor = self.factor.get(host, 1.0)
        runs.append((host, work_done * factor))
        if not elsewhere:
            return False  # nothing to compare with yet
        self.samples += 1
        figures = self._figures.setdefault(host, deque(maxlen=SAMPLES))
        figures.append(median(elsewhere) / work_done)
        bound = cfg.speed_max_correction
        seen = min(bound, max(1.0 / bound, median(figures)))
        if abs(math.log(seen / factor)) <= math.log1p(cfg.speed_deadband):
            return False
        self.factor[host] = seen
        self.corrections += 1
        return True
