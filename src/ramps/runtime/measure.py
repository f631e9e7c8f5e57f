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
from typing import Callable

import psutil

# what runs now (``MEASURING_PIDS`` and ``cgroup_usage`` are read from here too)
from ramps.runtime.runqueue import MEASURING_PIDS, CgroupThreads, cgroup_usage, own_running  # noqa: F401


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


class LoadSampler:
    """Samples busy cores and runnable tasks every ``interval`` seconds.

    The node's own threads (this sampler, Zenoh's) and its speed
    measurement's child are not counted as runnable: they wake together with every sample and report, so they
    biased an idle emulated robot's run queue to 0.1-0.6 tasks, which the
    weighted cost model reads as competing work. Worker processes (programs)
    are counted; on a cgroup, no more of their threads than programs run
    here, and none of the fork server's: a worker starting (to be kept warm,
    a fork server's fork) is the node's own work for a moment, which a robot
    of a fraction of a core read as "0.7 besides programs" and refused a
    program for (docs/lab/2026-11-28-claims-throttled.md).

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
                # a worker that runs no program (one starting, to be kept warm) is the node's, not load
                runnable = float(running - self._cg.workers + min(self._cg.workers, ramps))
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
