"""What a CPU second computes on this robot: its speed, measured by itself.

How this works: ``chunk_rates`` times small pieces of the burn program's
loop on this thread's own CPU clock, on each CPU this robot may use in turn,
against the loop's calibration, so 1.0 means "as fast as the reference
core"; ``chunk_rates_apart`` does the same in a forked child, away from the
node's other threads. ``SpeedSamples`` turns a node's measurements into its
figure (the fastest quarter of each CPU's pieces, the trimmed mean of the
latest measurements), and ``core_fraction`` scales it to a core under the
cgroup's quota (``ramps.runtime.measure.cpu_limit``). The node measures at
boot and on the team's wall-clock grid (``ramps.core.speed``).
"""

from __future__ import annotations

import math
import os
import select
import signal
import statistics
import time
from collections import deque
from typing import Callable

from ramps.runtime.measure import MEASURING_PIDS
from ramps.runtime.spin import ITERATIONS_PER_UNIT, spin


#: work units of one timed piece of a speed measurement (~1 ms of CPU on a
#: reference core, 2 ms on the development VM): shorter than the slice a
#: quota leaves a process in one period (a program capped at 0.08 of a CPU
#: gets 8 ms of every 100 ms), so a piece is rarely cut by throttling and
#: resumed on cold caches: with 5 ms pieces every one was, and the figures of
#: identical robots re-measured in capped processes drifted 1.02-1.08 apart
SPEED_CHUNK = 0.001
#: pieces timed on one CPU before the next (the first after a move is left
#: out: it warms the caches of its new CPU)
SPEED_BLOCK = 5
#: wall seconds a measurement may take at most: a robot starved of CPU by its
#: own software measures the pieces it got in that second. Identical robots
#: measuring at one moment of the team's grid then cover the same second of
#: the host, whose vCPUs change speed from one second to the next: with 5 s,
#: robots beside 8 busy processes each took 2.4-5.4 s for 0.2 s of CPU and
#: later moments started late (docs/lab/2026-11-26-speed-under-load.md)
SPEED_MAX_WALL = 1.0
#: measurements of a node's life its figure is the mean of (the newest): few
#: enough that robots booted seconds apart, measuring on one grid since,
#: average the same moments of the host 20 s after they are all up
SPEED_MEASUREMENTS = 6
#: measurements on the team's grid after which the boot measurement no longer
#: counts: one, since mixing the boot figure (each node's own second) with the
#: grid's (one second for all) set identical robots apart for longer
GRID_QUORUM = 1


def chunk_rates(seconds: float) -> dict[int, list[float]]:
    """What a CPU second computes here, piece by piece, per CPU: work units
    per CPU second of ``SPEED_CHUNK`` units of the burn loop each, timed on
    this thread's own CPU clock (``time.thread_time``), so neither waiting
    for the CPU (a quota's throttling, a run queue) nor the node's other
    threads count, until ``seconds`` of CPU are spent (over several quota
    periods under a quota) or ``SPEED_MAX_WALL`` have passed. The pieces
    run on each CPU this robot may use in turn, ``SPEED_BLOCK`` at a time
    (the measuring thread is pinned to one at a time; -1: the one it ran on
    where it cannot be pinned): a thread stays on one CPU for a while, and the development
    VM's two vCPUs ran the same loop at 0.36 and 0.57 units per CPU second
    for seconds on end, so a measurement that stayed on one said which vCPU
    it had landed on."""
    iterations = max(1, round(SPEED_CHUNK * ITERATIONS_PER_UNIT))
    pieces: dict[int, list[float]] = {}
    allowed = _affinity()
    cpus = sorted(allowed) if len(allowed) > 1 else [-1]
    cpu0, wall0 = time.thread_time(), time.monotonic()
    n = 0
    try:
        while n < 2 * len(cpus) or (time.thread_time() - cpu0 < seconds
                                    and time.monotonic() - wall0 < SPEED_MAX_WALL):
            cpu = cpus[n % len(cpus)]
            if cpu >= 0:
                _pin({cpu})
            for i in range(SPEED_BLOCK):
                start = time.thread_time()
                spin(iterations)
                if i:
                    pieces.setdefault(cpu, []).append(SPEED_CHUNK / max(time.thread_time() - start, 1e-6))
            n += 1
    finally:
        if cpus[0] >= 0:
            _pin(allowed)
    return pieces


#: seconds between two looks at ``chunk_rates_apart``'s ``stop`` while its child computes
STOP_POLL = 0.02


class Interrupted(Exception):
    """A measurement given up because its ``stop`` said so (a program started)."""


def chunk_rates_apart(seconds: float, stop: Callable[[], bool] | None = None) -> dict[int, list[float]]:
    """``chunk_rates`` in a forked child of this process: a node's other
    threads (its driver, Zenoh's callbacks, the load sampler) take the GIL
    from a measuring thread every few milliseconds, and its pieces, as long
    as a switch interval, then ran on cold caches: re-measured in the node,
    identical robots that had agreed within 5% at boot in 9 of 10 starts did
    in 5 of 10 afterwards. The child has only the forking thread, computes,
    writes its pieces to a pipe and leaves with ``os._exit``, in the node's
    cgroup and at its priority, as the boot measurement ran. Falls back to
    this thread where there is no ``fork``. ``stop``, asked every ``STOP_POLL``
    s while the child computes: when it says so, the child is killed and
    ``Interrupted`` raised, so a re-measurement never takes CPU from a program
    that starts meanwhile (on a robot of small quota-sliced cores the child, at
    the node's priority, takes the robot's whole quota for about a second)."""
    import msgspec

    if not hasattr(os, "fork"):
        return chunk_rates(seconds)
    r, w = os.pipe()
    pid = os.fork()
    if pid:
        MEASURING_PIDS.add(str(pid))
    if pid == 0:  # the child: no locks, no logging, no imports; computes and leaves
        code = 1
        try:
            os.close(r)
            data = msgspec.msgpack.encode({str(k): v for k, v in chunk_rates(seconds).items()})
            view = memoryview(data)
            while view:
                view = view[os.write(w, view):]
            code = 0
        finally:
            os._exit(code)
    os.close(w)
    try:
        chunks = []
        while True:
            if stop is not None and not select.select([r], [], [], STOP_POLL)[0]:
                if stop():
                    os.kill(pid, signal.SIGKILL)
                    raise Interrupted
                continue
            chunk = os.read(r, 65536)
            if not chunk:
                break
            chunks.append(chunk)
    finally:
        os.close(r)
        try:
            os.waitpid(pid, 0)
        except ChildProcessError:  # reaped already (SIGCHLD ignored by the embedding process)
            pass
        MEASURING_PIDS.discard(str(pid))
    got = msgspec.msgpack.decode(b"".join(chunks)) if chunks else {}
    return {int(k): [float(x) for x in v] for k, v in got.items()}


def _affinity() -> set[int]:
    try:
        return set(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return set()


def _pin(cpus: set[int]) -> None:
    """Run the calling thread (pid 0: this thread, not the process) on ``cpus``."""
    try:
        os.sched_setaffinity(0, cpus)
    except (AttributeError, OSError):
        pass


class SpeedSamples:
    """A node's measurements of what a CPU second computes, and the figure
    they give.

    One measurement's figure is the mean over the CPUs of the fastest
    quarter of the pieces timed on each (``fastest_quarter``): a piece the
    scheduler cut, resumed on cold caches or ran beside a busy hyperthread
    sibling only gets slower, so the fast pieces are the ones that say what
    the CPU computes (a median moves with how many pieces were cut).
    The node's figure is the mean of its latest ``SPEED_MEASUREMENTS``
    (boot and every re-measurement), without the fastest and the slowest
    once there are five. Identical robots measure at the same moments of
    the team's grid, so a mean over the same moments gives them the same
    figure even on a host whose vCPUs swing 1.4x from one moment to the
    next, where a median jumps between the moments' levels. The boot
    measurement is the one not taken on the grid (each node boots when it is
    started), so it counts only until ``GRID_QUORUM`` measurements of the
    grid are in
    (docs/lab/2026-11-27-fastest-pieces.md)."""

    def __init__(self) -> None:
        self._boot: float | None = None
        self._latest = 0.0
        self._figures: deque[float] = deque(maxlen=SPEED_MEASUREMENTS)

    def add(self, pieces: dict[int, list[float]], *, boot: bool = False) -> None:
        """One measurement's pieces; ``boot``: the measurement at the node's start."""
        rates = [fastest_quarter(good) for v in pieces.values()
                 if (good := [r for r in v if math.isfinite(r) and r > 0])]
        self._latest = statistics.fmean(rates) if rates else 0.0
        if not rates:
            return
        if boot:
            self._boot = self._latest
        else:
            self._figures.append(self._latest)

    @property
    def latest(self) -> float:
        """The figure of the latest measurement alone (0.0 before any, or when
        it timed nothing measurable)."""
        return self._latest

    def rate(self) -> float:
        """Work units per CPU second of this robot's CPUs (0.0 before any measurement)."""
        figures = list(self._figures)
        if self._boot is not None and len(figures) < GRID_QUORUM:
            figures.append(self._boot)
        if not figures:
            return 0.0
        if len(figures) >= 5:
            figures = sorted(figures)[1:-1]
        return statistics.fmean(figures)

    def se(self) -> float:
        """The relative standard error of ``rate``: the spread of the latest
        measurements' figures over the square root of their number (0.0
        before three)."""
        figures = [f for f in self._figures if f > 0]
        if len(figures) < 3:
            return 0.0
        logs = [math.log(f) for f in figures]
        return statistics.stdev(logs) / math.sqrt(len(logs))

    def speed(self, *, quota: float | None = None, cores: int = 1) -> float:
        """Work units per second of one of this robot's cores."""
        return round(self.rate() * core_fraction(quota, cores), 4)


def fastest_quarter(rates: list[float]) -> float:
    """The mean of the fastest quarter (at least one) of ``rates``."""
    fast = sorted(rates, reverse=True)
    return statistics.fmean(fast[:max(1, math.ceil(len(fast) / 4))])


def measure_speed(seconds: float = 0.2, *, quota: float | None = None, cores: int = 1,
                  samples: SpeedSamples | None = None, apart: bool = False, boot: bool = False,
                  stop: Callable[[], bool] | None = None) -> float:
    """Work units per second of one of this robot's cores (1.0 = the reference core).

    Two parts, measured apart: what a CPU second computes here
    (``chunk_rates`` for ``seconds`` of CPU, added to ``samples`` when given,
    the figure as ``SpeedSamples`` explains), and how much of a CPU each of
    the robot's cores is (the kernel's ``quota`` shared by ``cores``).
    ``apart``: in a forked child (``chunk_rates_apart``), for a process that
    runs other threads; ``boot``: the node's measurement at its start (see
    ``SpeedSamples``); ``stop``: give an ``apart`` measurement up when it says
    so (``Interrupted``, nothing added to ``samples``)."""
    samples = samples if samples is not None else SpeedSamples()
    samples.add(chunk_rates_apart(seconds, stop) if apart else chunk_rates(seconds), boot=boot)
    return samples.speed(quota=quota, cores=cores)


def core_fraction(quota: float | None, cores: int) -> float:
    """The share of a host core each of ``cores`` is under a quota of ``quota``
    cores (1.0 without one): a CPU second of a program is worth 1 / this
    seconds of one of the robot's cores."""
    return quota / cores if quota is not None and quota < cores else 1.0
