"""A simulated robot's processors: processor sharing over ``cores``.

How this works: with ``k`` ramps programs and ``b`` background processes on
``c`` cores, every task runs at ``speed * min(1, c / (k + b))`` work units
per second when all weigh the same; programs at a lower scheduler ``weight``
(a worker's niceness) get ``speed * cost.program_share(c, k, b, weight)``,
the background the rest. Time only moves forward through ``advance(now)``; adding or
removing a job first advances, then the rate changes. The CPU also keeps
running integrals of busy cores, runnable tasks and ramps programs, so the
load publisher can average them over its window exactly as a real robot's
``/proc/stat`` sampling would. A frozen robot (SIGSTOP) makes no progress.

An experiment, off by default (``CPU.most_work_left_first``): a robot
without background processes that holds more programs than cores runs
those with the most work left first, in its fluid form: the programs at
the highest level of work left run a core each, those tied at a level
share what cores are left, the others wait, and a level that falls to
the next joins it (an event: ``next_completion`` returns when). No
runtime does this (docs/lab/2026-11-28-sim-scale-5.md).
"""

from __future__ import annotations

import math
from collections import deque

from ramps.core.cost import program_share

Key = tuple[str, int]


class CPU:
    __slots__ = ("cores", "speed", "background", "weight", "jobs", "t", "frozen", "_hist", "_ib", "_ir", "_ik")

    #: run the programs with the most work left first where there are more
    #: programs than cores and no background (see the module docstring);
    #: False: processor sharing, what every robot does
    most_work_left_first: bool = False

    def __init__(self, cores: float, speed: float, background: int, now: float, weight: float = 1.0) -> None:
        self.cores = cores
        self.speed = speed
        self.background = background
        #: scheduler weight of a ramps program against a background process
        self.weight = weight
        #: remaining work per running program
        self.jobs: dict[Key, float] = {}
        self.t = now
        self.frozen = False
        # integrals of busy cores, runnable tasks, ramps programs since start
        self._ib = self._ir = self._ik = 0.0
        self._hist: deque[tuple[float, float, float, float, float, float, float]] = deque()
        self._mark()

    # ------------------------------------------------------------ rates
    def runnable(self) -> int:
        return 0 if self.frozen else len(self.jobs) + self.background

    def rate(self) -> float:
        """Work units per second each ramps program gets now."""
        n = self.runnable()
        if n == 0:
            return 0.0
        if self.weight == 1.0 or not self.background:
            return self.speed * min(1.0, self.cores / n)
        return self.speed * program_share(self.cores, len(self.jobs), self.background, self.weight)

    def _rates(self) -> tuple[float, float, float]:
        n = self.runnable()
        return float(min(self.cores, n)), float(n), 0.0 if self.frozen else float(len(self.jobs))

    def _mark(self) -> None:
        rb, rr, rk = self._rates()
        self._hist.append((self.t, self._ib, self._ir, self._ik, rb, rr, rk))

    # ------------------------------------------------------------ time
    def advance(self, now: float) -> None:
        dt = now - self.t
        if dt <= 0:
            return
        rb, rr, rk = self._rates()
        self._ib += rb * dt
        self._ir += rr * dt
        self._ik += rk * dt
        if self.jobs and not self.frozen:
            levels = self._levels() if self.most_work_left_first else None
            if levels is None:
                done = self.rate() * dt
                for key in self.jobs:
                    self.jobs[key] -= done
            else:
                jobs = self.jobs
                for level, keys, rate in levels:
                    left = level - rate * dt
                    for key in keys:
                        jobs[key] = left
        self.t = now

    def _levels(self) -> list[tuple[float, list[Key], float]] | None:
        """Most work left first (for ``most_work_left_first``): the programs
        by level of work left, highest first, each level's keys and the rate
        each of them runs at; None where processor sharing applies."""
        if self.background or len(self.jobs) <= self.cores:
            return None
        levels: list[tuple[float, list[Key], float]] = []
        free = self.cores
        for key in sorted(self.jobs, key=self.jobs.__getitem__, reverse=True):
            left = self.jobs[key]
            if levels and levels[-1][0] - left <= 1e-9:  # tied (a level that fell to this one)
                levels[-1][1].append(key)
                continue
            levels.append((left, [key], 0.0))
        out = []
        for level, keys, _ in levels:
            share = min(1.0, free / len(keys)) if free > 0 else 0.0
            free -= share * len(keys)
            out.append((level, keys, self.speed * share))
        return out

    def add(self, key: Key, work: float, now: float) -> None:
        self.advance(now)
        self.jobs[key] = work
        self._mark()

    def remove(self, key: Key, now: float) -> bool:
        self.advance(now)
        found = self.jobs.pop(key, None) is not None
        self._mark()
        return found

    def set_background(self, background: int, now: float) -> None:
        """The robot's own software now runs ``background`` busy processes."""
        self.advance(now)
        self.background = background
        self._mark()

    def set_frozen(self, frozen: bool, now: float) -> None:
        self.advance(now)
        self.frozen = frozen
        self._mark()

    def next_completion(self) -> tuple[float, Key] | None:
        """When the next job finishes if nothing changes, and which."""
        if not self.jobs or self.frozen:
            return None
        levels = self._levels() if self.most_work_left_first else None
        if levels is not None:  # the first level to fall to the next, or to end
            best = (math.inf, levels[0][1][0])
            for (level, keys, rate), below in zip(levels, levels[1:] + [(0.0, [], 0.0)]):
                if rate > below[2]:
                    best = min(best, (self.t + max(0.0, level - below[0]) / (rate - below[2]), keys[0]))
            return best
        key = min(self.jobs, key=self.jobs.__getitem__)
        return self.t + max(0.0, self.jobs[key]) / self.rate(), key

    def busy_seconds(self, now: float) -> float:
        """Core-seconds this CPU has been busy since it started, its programs
        and its busy processes alike (``ramps.sim.battery`` drains and counts
        energy by them)."""
        self.advance(now)
        return self._ib

    # ------------------------------------------------------------ measurement
    def averages(self, now: float, window: float) -> tuple[float, float, float]:
        """Mean busy cores, runnable tasks and ramps programs over the last
        ``window`` seconds (what a load publisher measures)."""
        self.advance(now)
        start = now - window
        hist = self._hist
        while len(hist) > 1 and hist[1][0] <= start:
            hist.popleft()
        t0, ib0, ir0, ik0, rb, rr, rk = hist[0]
        if start < t0:  # the robot has not been up for a whole window
            start, window = t0, max(now - t0, 1e-9)
        d = start - t0
        ib, ir, ik = ib0 + rb * d, ir0 + rr * d, ik0 + rk * d
        return (self._ib - ib) / window, (self._ir - ir) / window, (self._ik - ik) / window


# ---------------------------------------------------------------- a robot's pools
# A robot's CPU and its accelerators (``ramps.core.accelerators``: slots
# shared like cores, no background) are each a ``CPU``; these act on all.
def next_completion(pools: tuple[CPU, ...]) -> float | None:
    """When the first job of any of ``pools`` finishes if nothing changes."""
    ends = [nxt[0] for pool in pools if (nxt := pool.next_completion()) is not None]
    return min(ends) if ends else None


def take_finished(pools: tuple[CPU, ...], now: float) -> list[Key]:
    """The jobs of ``pools`` that have finished by ``now``, taken out."""
    finished = []
    for pool in pools:
        pool.advance(now)
        ended = [key for key, left in pool.jobs.items() if left <= 1e-9]
        for key in ended:
            pool.remove(key, now)
        finished += ended
    return finished


def set_frozen(pools: tuple[CPU, ...], frozen: bool, now: float) -> None:
    for pool in pools:
        pool.set_frozen(frozen, now)
