"""What a load publisher measures on a real robot.

How this works: a sampler thread reads the CPU every ``interval`` seconds
and keeps the samples of the last ``window`` seconds; ``averages()`` returns
what a ``LoadReport`` needs: busy cores, runnable tasks (the run queue, like
load average but over the window, so 8 ``stress`` processes count as 8) and
ramps programs. Two scopes:

* ``host``: the whole machine (``/proc/stat`` and ``psutil``): a robot that
  is one computer;
* ``cgroup``: only the processes of this node's cpu cgroup (v1 or v2), for
  emulated robots that share one host (the testbed, ``ramps demo``).

``detect_cores`` respects CPU affinity and the cgroup CPU quotas
(``cpu_limit``: the smallest along the cgroup's path); ``measure_speed``
times a fixed amount of work on the thread's own CPU clock against the burn
program's calibration, so speed 1.0 means "as fast as the reference core".
"""

from __future__ import annotations

import math
import os
import statistics
import threading
import time
from collections import deque
from pathlib import Path
from typing import Callable, Iterable

import psutil

from ramps.runtime.spin import ITERATIONS_PER_UNIT, spin


def _own_cgroups() -> dict[str, str]:
    """controller -> path of this process, from /proc/self/cgroup."""
    out: dict[str, str] = {}
    try:
        lines = Path("/proc/self/cgroup").read_text().splitlines()
    except OSError:
        return out
    for line in lines:
        _, controllers, path = line.split(":", 2)
        for c in controllers.split(",") if controllers else [""]:
            out[c] = path
    return out


def cgroup_dirs() -> tuple[Path | None, Path | None]:
    """(cpu dir with the quota, dir with CPU usage) of this process's cgroup,
    for cgroup v2 (one unified dir) or v1 (cpu and cpuacct, maybe co-mounted)."""
    own = _own_cgroups()
    root = Path("/sys/fs/cgroup")
    if (root / "cgroup.controllers").exists() and "" in own:
        d = root / own[""].lstrip("/")
        return d, d
    cpu = acct = None
    if "cpu" in own:
        for name in ("cpu,cpuacct", "cpu"):
            if (root / name).exists():
                cpu = root / name / own["cpu"].lstrip("/")
                break
    if "cpuacct" in own:
        for name in ("cpu,cpuacct", "cpuacct"):
            if (root / name / "cpuacct.usage").exists():
                acct = root / name / own["cpuacct"].lstrip("/")
                break
    return cpu, acct


def cgroup_cpu_dir() -> Path | None:
    return cgroup_dirs()[0]


def cgroup_quota(d: Path | None) -> float | None:
    """CPU quota of one cgroup in cores (``cpu.max`` on v2, ``cpu.cfs_quota_us``
    / ``cpu.cfs_period_us`` on v1), or None when it sets none."""
    if d is None:
        return None
    try:
        if (d / "cpu.max").exists():
            quota, period = (d / "cpu.max").read_text().split()
            return None if quota == "max" else int(quota) / int(period)
        q = int((d / "cpu.cfs_quota_us").read_text())
        p = int((d / "cpu.cfs_period_us").read_text())
        return None if q <= 0 else q / p
    except (OSError, ValueError):
        return None


def cpu_limit(d: Path | None) -> float | None:
    """The CPU this process may use, in cores, as the kernel states it: the
    smallest quota of its cgroup and every cgroup above it (a container's
    limit is often set on a parent: a pod, a slice), or None when none
    sets one. Affinity is ``detect_cores``' business."""
    if d is None:
        return None
    root = Path("/sys/fs/cgroup")
    limits = []
    here = d
    while True:
        q = cgroup_quota(here)
        if q is not None:
            limits.append(q)
        if here == here.parent or here.parent == root or here == root:
            break
        here = here.parent
    return min(limits) if limits else None


def detect_cores() -> int:
    n = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    quota = cpu_limit(cgroup_cpu_dir())
    if quota is not None:
        n = min(n, max(1, math.floor(quota + 0.5)))
    return max(1, n)


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


#: pids of this process's measuring children (``chunk_rates_apart``) now
#: running: the node's own work, like its threads, not load of the robot's
#: (counted, a re-measurement made every idle robot look busy for a second to
#: origins placing then, which put their programs elsewhere)
_measuring: set[str] = set()


def chunk_rates_apart(seconds: float) -> dict[int, list[float]]:
    """``chunk_rates`` in a forked child of this process: a node's other
    threads (its driver, Zenoh's callbacks, the load sampler) take the GIL
    from a measuring thread every few milliseconds, and its pieces, as long
    as a switch interval, then ran on cold caches: re-measured in the node,
    identical robots that had agreed within 5% at boot in 9 of 10 starts did
    in 5 of 10 afterwards. The child has only the forking thread, computes,
    writes its pieces to a pipe and leaves with ``os._exit``, in the node's
    cgroup and at its priority, as the boot measurement ran. Falls back to
    this thread where there is no ``fork``."""
    import msgspec

    if not hasattr(os, "fork"):
        return chunk_rates(seconds)
    r, w = os.pipe()
    pid = os.fork()
    if pid:
        _measuring.add(str(pid))
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
        while chunk := os.read(r, 65536):
            chunks.append(chunk)
    finally:
        os.close(r)
        try:
            os.waitpid(pid, 0)
        except ChildProcessError:  # reaped already (SIGCHLD ignored by the embedding process)
            pass
        _measuring.discard(str(pid))
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
        if not rates:
            return
        self._latest = statistics.fmean(rates)
        if boot:
            self._boot = self._latest
        else:
            self._figures.append(self._latest)

    @property
    def latest(self) -> float:
        """The figure of the latest measurement alone (0.0 before any)."""
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

    def speed(self, *, quota: float | None = None, cores: int = 1) -> float:
        """Work units per second of one of this robot's cores."""
        return round(self.rate() * core_fraction(quota, cores), 4)


def fastest_quarter(rates: list[float]) -> float:
    """The mean of the fastest quarter (at least one) of ``rates``."""
    fast = sorted(rates, reverse=True)
    return statistics.fmean(fast[:max(1, math.ceil(len(fast) / 4))])


def measure_speed(seconds: float = 0.2, *, quota: float | None = None, cores: int = 1,
                  samples: SpeedSamples | None = None, apart: bool = False, boot: bool = False) -> float:
    """Work units per second of one of this robot's cores (1.0 = the reference core).

    Two parts, measured apart: what a CPU second computes here
    (``chunk_rates`` for ``seconds`` of CPU, added to ``samples`` when given,
    the figure as ``SpeedSamples`` explains), and how much of a CPU each of
    the robot's cores is (the kernel's ``quota`` shared by ``cores``).
    ``apart``: in a forked child (``chunk_rates_apart``), for a process that
    runs other threads; ``boot``: the node's measurement at its start (see
    ``SpeedSamples``)."""
    samples = samples if samples is not None else SpeedSamples()
    samples.add(chunk_rates_apart(seconds) if apart else chunk_rates(seconds), boot=boot)
    return samples.speed(quota=quota, cores=cores)


def core_fraction(quota: float | None, cores: int) -> float:
    """The share of a host core each of ``cores`` is under a quota of ``quota``
    cores (1.0 without one): a CPU second of a program is worth 1 / this
    seconds of one of the robot's cores."""
    return quota / cores if quota is not None and quota < cores else 1.0


def _procs_running() -> int:
    try:
        with open("/proc/stat", "rb") as f:
            for line in f:
                if line.startswith(b"procs_running"):
                    return int(line.split()[1])
    except OSError:
        pass
    return int(os.getloadavg()[0])


def proc_stat_fields(pid: int) -> list[str] | None:
    """The fields of ``/proc/<pid>/stat`` after the command name, from the
    state (field 3 of proc(5), index 0 here), or None if the process is gone."""
    try:
        raw = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    return raw[raw.rindex(")") + 2:].split()


_CLOCK_TICKS = os.sysconf("SC_CLK_TCK")


def proc_cpu(pid: int) -> tuple[float, str] | None:
    """(CPU seconds a process has used, user and system, and its state: ``R``
    running or runnable, ``S`` sleeping, ...), or None if it is gone."""
    rest = proc_stat_fields(pid)
    if rest is None:
        return None
    return (int(rest[11]) + int(rest[12])) / _CLOCK_TICKS, rest[0]


def cgroup_tree(d: Path | str) -> list[Path]:
    """A cgroup and every cgroup below it (the testbed caps each program in a
    child of its robot's), deepest first, so they can be removed in order."""
    dirs = [Path(sub) for sub, _, _ in os.walk(d)]
    return sorted(dirs, key=lambda p: len(p.parts), reverse=True)


def cgroup_usage(cpu: Path, acct: Path | None) -> float:
    """CPU seconds used so far by a cgroup and its children (0.0 if unreadable):
    cpuacct.usage on v1, cpu.stat's usage_usec on v2."""
    try:
        if acct is not None and (acct / "cpuacct.usage").exists():
            return int((acct / "cpuacct.usage").read_text()) / 1e9
        if (cpu / "cpu.stat").exists():
            for line in (cpu / "cpu.stat").read_text().splitlines():
                if line.startswith("usage_usec"):
                    return int(line.split()[1]) / 1e6
    except (OSError, ValueError):
        pass
    return 0.0


def _running(paths: Iterable[str]) -> int:
    """How many of these ``/proc/.../stat`` files say state R (running or runnable).
    Plain ``os.open``/``os.read``: the sampler reads one per thread of the robot
    ten times a second, and ``open()``'s buffered file objects doubled its CPU."""
    running = 0
    for path in paths:
        try:
            fd = os.open(path, os.O_RDONLY)
        except OSError:
            continue
        try:
            data = os.read(fd, 1024)  # a stat line is a few hundred bytes; the state follows the name
        except OSError:
            continue
        finally:
            os.close(fd)
        end = data.rfind(b")")
        if end > 0 and data[end + 2:end + 3] == b"R":
            running += 1
    return running


def _cgroup_dirs(top: str) -> list[str]:
    """A cgroup and every cgroup below it, in no particular order (cheaper than
    ``cgroup_tree``, which the sampler called ten times a second)."""
    out, stack = [], [top]
    while stack:
        d = stack.pop()
        out.append(d)
        try:
            with os.scandir(d) as it:
                stack.extend(e.path for e in it if e.is_dir(follow_symlinks=False))
        except OSError:
            continue
    return out


def _read_all(path: str) -> bytes:
    fd = os.open(path, os.O_RDONLY)
    try:
        chunks = []
        while chunk := os.read(fd, 65536):
            chunks.append(chunk)
        return b"".join(chunks)
    finally:
        os.close(fd)


def _own_threads() -> set[str]:
    try:
        return set(os.listdir("/proc/self/task"))
    except OSError:
        return set()


def own_running() -> int:
    """This process's threads in state R now (the sampler itself included),
    and its measuring child if it runs one."""
    return _running([f"/proc/self/task/{tid}/stat" for tid in _own_threads()]
                    + [f"/proc/{pid}/stat" for pid in list(_measuring)])


def _cgroup_usage_and_runnable(cpu: Path, acct: Path | None) -> tuple[float, int]:
    """CPU seconds used so far by a cgroup, and its threads in state R now,
    other than this process's own (the node: see ``LoadSampler``)."""
    usage = cgroup_usage(cpu, acct)
    tids: list[str] = []
    v1 = not os.path.exists(os.path.join(cpu, "cgroup.threads"))  # v1 lists a cgroup's threads in ``tasks``
    for sub in _cgroup_dirs(str(cpu)):
        try:
            tids += _read_all(os.path.join(sub, "tasks" if v1 else "cgroup.threads")).decode().split()
        except OSError:
            continue
    own = _own_threads() | _measuring
    return usage, _running(f"/proc/{tid}/stat" for tid in tids if tid not in own)


class LoadSampler:
    """Samples busy cores and runnable tasks every ``interval`` seconds.

    The node's own threads (this sampler, Zenoh's) and its speed
    measurement's child are not counted as runnable: they wake together with every sample and report, so they
    biased an idle emulated robot's run queue to 0.1-0.6 tasks, which the
    weighted cost model reads as competing work. Worker processes (programs)
    are counted.

    Every 0.2 s by default (5 samples a window): reading the run queue of an
    emulated robot's cgroup was most of an idle node's CPU (0.7-1.4 ms a
    sample; at 10 samples a second, 0.3 of an emulated core of 0.05 host
    cores, which its programs then lacked)."""

    def __init__(self, ramps_count: Callable[[], int], *, window: float = 1.0, interval: float = 0.2,
                 scope: str = "host", cgroup: Path | None = None, acct: Path | None = None) -> None:
        self.window = window
        self.interval = interval
        self.scope = scope
        self.cgroup = cgroup
        self.acct = acct
        self._ramps_count = ramps_count
        self._samples: deque[tuple[float, float, float, float]] = deque()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="ramps-load", daemon=True)

    def start(self) -> None:
        psutil.cpu_percent(percpu=False)
        self._last_usage = _cgroup_usage_and_runnable(self.cgroup, self.acct)[0] if self.cgroup else 0.0
        self._last_t = time.monotonic()
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()

    def _run(self) -> None:
        ncpu = psutil.cpu_count() or 1
        while not self._stop.wait(self.interval):
            now = time.monotonic()
            ramps = float(self._ramps_count())
            if self.scope == "cgroup" and self.cgroup is not None:
                usage, running = _cgroup_usage_and_runnable(self.cgroup, self.acct)
                busy = max(0.0, (usage - self._last_usage) / max(now - self._last_t, 1e-6))
                self._last_usage = usage
                runnable = float(running)
            else:
                busy = psutil.cpu_percent(percpu=False) / 100.0 * ncpu
                # less the node's own running threads, this sampler among them; reading
                # them costs ~0.5 ms, so only when something besides the sampler runs
                host = _procs_running()
                runnable = float(max(0, host - (own_running() if host > 1 else 1)))
            self._last_t = now
            with self._lock:
                self._samples.append((now, busy, max(runnable, ramps), ramps))
                while self._samples and self._samples[0][0] < now - self.window:
                    self._samples.popleft()

    def extras(self) -> tuple[list[float], float, int]:
        """(CPU use per core 0..1 since the last call, 1-minute load average,
        bytes of memory available): the rest of a load report."""
        per_core = [round(x / 100.0, 3) for x in psutil.cpu_percent(percpu=True)]
        try:
            load1 = os.getloadavg()[0]
        except OSError:
            load1 = 0.0
        return per_core, load1, int(psutil.virtual_memory().available)

    def averages(self) -> tuple[float, float, float]:
        """(busy cores, runnable tasks, ramps programs) over the window."""
        with self._lock:
            s = list(self._samples)
        if not s:
            r = float(self._ramps_count())
            return 0.0, r, r
        n = len(s)
        return (sum(x[1] for x in s) / n, sum(x[2] for x in s) / n, sum(x[3] for x in s) / n)
