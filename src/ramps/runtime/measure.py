"""What a load publisher measures on a real robot.

How this works: a sampler thread reads the CPU every ``interval`` seconds
(``idle_interval`` while no program runs) and keeps the samples of the last
``window`` seconds; ``averages()`` returns what a ``LoadReport`` needs: busy cores, runnable tasks (the run queue, like
load average but over the window, so 8 ``stress`` processes count as 8) and
ramps programs. Two scopes:

* ``host``: the whole machine (``/proc/stat`` and ``psutil``): a robot that
  is one computer;
* ``cgroup``: only the processes of this node's cpu cgroup (v1 or v2), for
  emulated robots that share one host (the testbed, ``ramps demo``).

``detect_cores`` respects CPU affinity and the cgroup CPU quotas
(``cpu_limit``: the smallest along the cgroup's path). What a CPU second
computes here is ``ramps.runtime.speed_probe``'s business.
"""

from __future__ import annotations

import math
import os
import threading
import time
from collections import deque
from pathlib import Path
from typing import Callable, Iterable

import psutil


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


def cpu_model() -> str:
    """This machine's CPU model as ``/proc/cpuinfo`` names it (``model name``,
    else ``Hardware`` or the implementer and part), and the board's where it
    names one (``Model`` on a Raspberry Pi), at most 128 characters; the
    architecture where it says none: robots of one model measure alike
    (``ramps.core.speed.SpeedClass``)."""
    fields: dict[str, str] = {}
    try:
        for line in Path("/proc/cpuinfo").read_text(errors="replace").splitlines():
            key, sep, value = line.partition(":")
            if sep and value.strip():
                fields.setdefault(key.strip().lower(), " ".join(value.split()))
    except OSError:
        pass
    cpu = fields.get("model name") or fields.get("cpu model") or fields.get("hardware")
    if cpu is None and "cpu part" in fields:
        cpu = f"{fields.get('cpu implementer', '?')}:{fields['cpu part']}"
    board = fields.get("model", "")  # a board's name on ARM; a number on x86
    parts = [x for x in (cpu, "" if board.isdigit() else board) if x]
    return " / ".join(parts)[:128] or os.uname().machine[:128] or "unknown"


#: pids of this process's measuring children (``speed_probe.chunk_rates_apart``) now running: the node's
#: own work, not the robot's load (counted, a re-measurement made idle robots look busy for a second)
MEASURING_PIDS: set[str] = set()


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
    return _stat_fields(raw)


def _stat_fields(raw: str) -> list[str]:
    """A ``stat`` line's fields after the command name (which may hold spaces and brackets)."""
    return raw[raw.rindex(")") + 2:].split()


def _cpu_and_state(rest: list[str]) -> tuple[float, str]:
    """(user + system CPU seconds, state) of a ``stat`` line's fields after the name."""
    return (int(rest[11]) + int(rest[12])) / _CLOCK_TICKS, rest[0]


_CLOCK_TICKS = os.sysconf("SC_CLK_TCK")


def proc_cpu(pid: int) -> tuple[float, str] | None:
    """(CPU seconds a process has used, user and system, and its state: ``R``
    running or runnable, ``S`` sleeping, ...), or None if it is gone."""
    rest = proc_stat_fields(pid)
    return None if rest is None else _cpu_and_state(rest)


def stat_cpu(fd: int) -> tuple[float, str] | None:
    """``proc_cpu`` from an open ``/proc/<pid>/stat`` (read again with ``pread``:
    opening it by path cost the worker pool more than reading), None if the
    process is gone."""
    try:
        raw = os.pread(fd, 1024, 0)
    except OSError:
        return None
    return _cpu_and_state(_stat_fields(raw.decode()))


def cgroup_tree(d: Path | str) -> list[Path]:
    """A cgroup and every cgroup below it (the testbed caps each program in a
    child of its robot's), deepest first, so they can be removed in order."""
    dirs = [Path(sub) for sub, _, _ in os.walk(d)]
    return sorted(dirs, key=lambda p: len(p.parts), reverse=True)


def cgroup_usage(cpu: Path, acct: Path | None) -> float:
    """CPU seconds used so far by a cgroup and its children (0.0 if unreadable):
    cpuacct.usage on v1, cpu.stat's usage_usec on v2."""
    try:
        f = _usage_file(cpu, acct)
        return 0.0 if f is None else _usage_seconds(f.read_bytes(), v2=f.name == "cpu.stat")
    except (OSError, ValueError):
        return 0.0


def _usage_file(cpu: Path, acct: Path | None) -> Path | None:
    """The file that counts a cgroup's CPU: ``cpuacct.usage`` (v1), else ``cpu.stat`` (v2), if either is there."""
    if acct is not None and (acct / "cpuacct.usage").exists():
        return acct / "cpuacct.usage"
    return cpu / "cpu.stat" if (cpu / "cpu.stat").exists() else None


def _usage_seconds(data: bytes, *, v2: bool) -> float:
    """CPU seconds from ``_usage_file``'s text: nanoseconds (v1), or its ``usage_usec`` line (v2)."""
    if not v2:
        return int(data) / 1e9
    for line in data.splitlines():
        if line.startswith(b"usage_usec"):
            return int(line.split()[1]) / 1e6
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
        running += _is_running(data)
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


def _is_running(stat: bytes) -> bool:
    """Whether a ``/proc/.../stat`` line says state R (it follows the name's ``)``)."""
    end = stat.rfind(b")")
    return end > 0 and stat[end + 2:end + 3] == b"R"


class OwnThreads:
    """This process's threads' ``stat`` files, kept open and read again with
    ``pread`` (opening ~30 by path was 241 against 96 us a read); listed again
    every ``RELIST`` reads (threads come and go), an ended one dropped."""

    RELIST = 10

    def __init__(self) -> None:
        self.fds: dict[str, int] = {}
        self._reads = 0
        self._lock = threading.Lock()

    def running(self) -> int:
        """How many of this process's threads are in state R now."""
        with self._lock:
            if self._reads % self.RELIST == 0:
                self._relist()
            self._reads += 1
            n = 0
            for tid, fd in list(self.fds.items()):
                try:
                    data = os.pread(fd, 1024, 0)
                except OSError:  # the thread ended
                    os.close(fd)
                    del self.fds[tid]
                    continue
                n += _is_running(data)
            return n

    def tids(self) -> set[str]:
        """This process's thread ids as last listed (at most ``RELIST`` reads ago)."""
        with self._lock:
            if not self.fds:
                self._relist()
            return set(self.fds)

    def _relist(self) -> None:
        tids = _own_threads()
        for tid in [t for t in self.fds if t not in tids]:
            os.close(self.fds.pop(tid))
        for tid in tids - self.fds.keys():
            try:
                self.fds[tid] = os.open(f"/proc/self/task/{tid}/stat", os.O_RDONLY)
            except OSError:
                continue


_OWN = OwnThreads()


def own_running() -> int:
    """This process's threads in state R now (the sampler itself included),
    and its measuring child if it runs one."""
    return _OWN.running() + _running([f"/proc/{pid}/stat" for pid in list(MEASURING_PIDS)])


class CgroupThreads:
    """A cgroup's CPU usage and its threads in state R, other than this process's own (the node: see
    ``LoadSampler``). The usage file and each thread's ``stat`` stay open, read again with ``pread`` (opening
    each by path, some 250 us a sample, was most of an idle emulated robot's node); the ``tasks`` (v1) or
    ``cgroup.threads`` (v2) files are opened afresh each sample (an open one keeps the list it first read), and
    the cgroups below (per-program caps) listed again every ``RELIST`` samples."""

    RELIST = 5

    def __init__(self, cpu: Path, acct: Path | None) -> None:
        self.cpu, self.acct = cpu, acct
        self.v1 = not os.path.exists(os.path.join(cpu, "cgroup.threads"))  # v1 lists threads in ``tasks``
        self._usage_fd: int | None = None
        self._usage_v2 = False
        self._lists: list[str] = []  # the tasks files of the cgroup and those below it
        self._stats: dict[str, int] = {}  # thread id -> its open stat file
        self._samples = 0
        f = _usage_file(cpu, acct)
        try:
            if f is not None:
                self._usage_fd, self._usage_v2 = os.open(f, os.O_RDONLY), f.name == "cpu.stat"
        except OSError:
            self._usage_fd = None

    def usage(self) -> float:
        """CPU seconds used so far by the cgroup and its children (0.0 if unreadable)."""
        if self._usage_fd is None:
            return cgroup_usage(self.cpu, self.acct)
        try:
            return _usage_seconds(os.pread(self._usage_fd, 4096, 0), v2=self._usage_v2)
        except (OSError, ValueError):
            return 0.0

    def sample(self) -> tuple[float, int]:
        """(CPU seconds so far, threads in state R now other than this process's)."""
        usage = self.usage()
        if self._samples % self.RELIST == 0:
            self._relist()
        self._samples += 1
        own = _OWN.tids() | MEASURING_PIDS
        listed: set[str] = set()
        for path in self._lists:
            try:
                listed.update(_read_all(path).decode().split())
            except OSError:  # the cgroup went away
                continue
        for tid in [t for t in self._stats if t not in listed]:
            os.close(self._stats.pop(tid))
        running = 0
        for tid in listed - own:
            if tid not in self._stats:
                try:
                    self._stats[tid] = os.open(f"/proc/{tid}/stat", os.O_RDONLY)
                except OSError:
                    continue
            try:
                running += _is_running(os.pread(self._stats[tid], 1024, 0))
            except OSError:  # the thread ended
                os.close(self._stats.pop(tid))
        return usage, running

    def close(self) -> None:
        for fd in [*self._stats.values(), *([self._usage_fd] if self._usage_fd else [])]:
            os.close(fd)
        self._stats.clear()
        self._usage_fd = None

    def _relist(self) -> None:
        name = "tasks" if self.v1 else "cgroup.threads"
        self._lists = [os.path.join(d, name) for d in _cgroup_dirs(str(self.cpu))]


class LoadSampler:
    """Samples busy cores and runnable tasks every ``interval`` seconds.

    The node's own threads (this sampler, Zenoh's) and its speed
    measurement's child are not counted as runnable: they wake together with every sample and report, so they
    biased an idle emulated robot's run queue to 0.1-0.6 tasks, which the
    weighted cost model reads as competing work. Worker processes (programs)
    are counted.

    Every 0.2 s by default (5 samples a window), every ``idle_interval`` while
    no program runs here: a sample reads the node's ~30 threads' state
    (``own_running``, ~100 us) or a cgroup's (``CgroupThreads``), about two
    thirds of an idle node's CPU (docs/lab/2026-11-27-cgroup-sampler.md)."""

    def __init__(self, ramps_count: Callable[[], int], *, window: float = 1.0, interval: float = 0.2,
                 idle_interval: float = 0.4, scope: str = "host", cgroup: Path | None = None,
                 acct: Path | None = None) -> None:
        self.window = window
        self.interval = interval
        self.idle_interval = max(interval, idle_interval)
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
        self._cg = CgroupThreads(self.cgroup, self.acct) if self.scope == "cgroup" and self.cgroup else None
        self._last_usage = self._cg.usage() if self._cg else 0.0
        self._last_t = time.monotonic()
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()

    def _run(self) -> None:
        ncpu = psutil.cpu_count() or 1
        wait = self.interval
        while not self._stop.wait(wait):
            now = time.monotonic()
            ramps = float(self._ramps_count())
            wait = self.interval if ramps > 0 else self.idle_interval
            if self._cg is not None:
                usage, running = self._cg.sample()
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
        if self._cg is not None:
            self._cg.close()

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
