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
"""

from __future__ import annotations

from collections import deque

from ramps.core.cost import program_share

Key = tuple[str, int]


class CPU:
    __slots__ = ("cores", "speed", "background", "weight", "jobs", "t", "frozen", "_hist", "_ib", "_ir", "_ik")

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
            done = self.rate() * dt
            for key in self.jobs:
                self.jobs[key] -= done
        self.t = now

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
