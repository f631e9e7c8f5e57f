"""Which tasks of a robot are running now: this node's own threads, and a cgroup's.

How this works: each thread's ``/proc/.../stat`` file is kept open and read again with ``pread``;
the lists of threads are read again every few samples (``RELIST``). ``ramps.runtime.measure``'s
``LoadSampler`` reads these every sample.
"""

from __future__ import annotations

import os
import threading
from pathlib import Path
from typing import Iterable

from ramps.runtime.forkserver import FORK_SERVER_NAME, WORKER_NAME

#: pids of this process's measuring children (``speed_probe.chunk_rates_apart``) now running: the node's
#: own work, not the robot's load (counted, a re-measurement made idle robots look busy for a second)
MEASURING_PIDS: set[str] = set()


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


def _kind(stat: bytes) -> int:
    """0: not running; 1: running; 2: a fork server's thread running; 3: a worker's
    (by the names ``ramps.runtime.forkserver`` gives them)."""
    end = stat.rfind(b")")
    if end <= 0 or stat[end + 2:end + 3] != b"R":
        return 0
    name = stat[stat.find(b"(") + 1:end]
    return 2 if name == FORK_SERVER_NAME else 3 if name == WORKER_NAME else 1


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
        #: of the threads running at the last sample, those of this node's workers
        self.workers = 0
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
        """(CPU seconds so far, threads in state R now other than this process's and its
        fork server's); ``workers``: how many of them are its workers' (programs, or a worker
        starting: ``LoadSampler`` counts no more of them than programs run)."""
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
        counts = [0, 0, 0, 0]
        for tid in listed - own:
            if tid not in self._stats:
                if os.path.exists(f"/proc/self/task/{tid}"):
                    continue  # a thread this node started since its own were listed (a burst's)
                try:
                    self._stats[tid] = os.open(f"/proc/{tid}/stat", os.O_RDONLY)
                except OSError:
                    continue
            try:
                counts[_kind(os.pread(self._stats[tid], 1024, 0))] += 1
            except OSError:  # the thread ended
                os.close(self._stats.pop(tid))
        self.workers = counts[3]
        return usage, counts[1] + counts[3]

    def close(self) -> None:
        for fd in [*self._stats.values(), *([self._usage_fd] if self._usage_fd else [])]:
            os.close(fd)
        self._stats.clear()
        self._usage_fd = None

    def _relist(self) -> None:
        name = "tasks" if self.v1 else "cgroup.threads"
        self._lists = [os.path.join(d, name) for d in _cgroup_dirs(str(self.cpu))]
