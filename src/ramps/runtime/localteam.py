"""What a team of robots on one machine needs: free loopback ports (below the
ephemeral range, so parallel test processes and outgoing connections do not
take them), cpu
cgroups that make a process tree a small computer of a given number of host
cores (v1 or v2), and the rule for "every robot sees all the others".

Used by ``ramps.testing.LocalTeam`` (real node processes on loopback: the
demo, the benchmarks, the end-to-end tests) and by the testbed.
"""

from __future__ import annotations

import os
import random
import socket
import time
from pathlib import Path

from ramps.runtime.measure import cgroup_tree

CG_ROOT = Path("/sys/fs/cgroup")


def partial_views(sees: dict[str, int | None], size: int) -> dict[str, int | None]:
    """Of a team of ``size`` running robots, those whose own load reports say
    they do not see all ``size - 1`` others yet (None: no count reported),
    with what they see. Teams are handed over only when this is empty."""
    return {robot: n for robot, n in sees.items() if (n or 0) < size - 1}


#: ports handed out by this process (never given twice, even once free again)
_GIVEN: set[int] = set()
_PICK = random.Random()  # seeded from the OS: processes side by side pick differently


def _ephemeral_range() -> tuple[int, int]:
    try:
        lo, hi = Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()
        return int(lo), int(hi)
    except (OSError, ValueError):
        return 32768, 60999


def free_port() -> int:
    """A loopback TCP port that nothing listens on now, for a node to listen on.

    Picked at random below the kernel's ephemeral range (10000 up to it), so
    an outgoing connection (a client, another test's session) is never given
    it by the kernel between this check and the node binding it, and test
    processes running side by side (pytest-xdist workers) rarely try the
    same one; a port in use is skipped (the bind check) and none is handed
    out twice by one process. Falls back to a kernel-chosen port when the
    ephemeral range leaves no room below it."""
    lo = 10000
    hi = _ephemeral_range()[0]
    if hi - lo >= 1000:
        for _ in range(200):
            port = _PICK.randrange(lo, hi)
            if port in _GIVEN:
                continue
            with socket.socket() as s:
                try:
                    s.bind(("127.0.0.1", port))
                except OSError:
                    continue
            _GIVEN.add(port)
            return port
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    _GIVEN.add(port)
    return port


def listening_ports() -> set[int] | None:
    """The TCP ports something listens on in this network namespace (from
    ``/proc/net/tcp*``: cheaper than asking every process), None if unreadable."""
    ports: set[int] = set()
    try:
        for table in ("/proc/net/tcp", "/proc/net/tcp6"):
            with open(table) as f:
                next(f)
                for line in f:
                    fields = line.split()
                    if fields[3] == "0A":  # LISTEN
                        ports.add(int(fields[1].rsplit(":", 1)[1], 16))
    except (OSError, ValueError, IndexError, StopIteration):
        return None
    return ports


def cgroup_mode() -> str | None:
    """'v2', 'v1' or None when this process cannot make cpu cgroups."""
    if os.geteuid() != 0:
        return None
    if (CG_ROOT / "cgroup.controllers").exists():
        if "cpu" in (CG_ROOT / "cgroup.controllers").read_text().split() and os.access(CG_ROOT, os.W_OK):
            return "v2"
        return None
    if (CG_ROOT / "cpu" / "cpu.cfs_quota_us").exists() and os.access(CG_ROOT / "cpu", os.W_OK):
        return "v1"
    return None


class RobotCgroup:
    """One robot's cpu cgroup (and cpuacct on v1, for its CPU usage)."""

    def __init__(self, name: str, quota: float, mode: str, period: int = 100_000) -> None:
        """``period``: the CFS period, microseconds: the kernel holds the quota over each (a
        program shorter than one period's quota runs at full host speed)."""
        self.mode = mode
        if mode == "v2":
            self.dirs = [CG_ROOT / name]
            self.dirs[0].mkdir()
            (self.dirs[0] / "cpu.max").write_text(f"{int(quota * period)} {period}")
        else:
            self.dirs = [CG_ROOT / "cpu" / name]
            self.dirs[0].mkdir()
            (self.dirs[0] / "cpu.cfs_period_us").write_text(str(period))
            (self.dirs[0] / "cpu.cfs_quota_us").write_text(str(int(quota * period)))
            acct = CG_ROOT / "cpuacct" / name
            if (CG_ROOT / "cpuacct" / "cpuacct.usage").exists():
                acct.mkdir()
                self.dirs.append(acct)

    def enter(self) -> None:
        """Move the calling process in (used between fork and exec)."""
        for d in self.dirs:
            (d / "cgroup.procs").write_text(str(os.getpid()))

    def wrap(self, argv: list[str]) -> list[str]:
        """``argv`` run inside this cgroup from its first instruction, with no
        preexec hook: a shell joins the cgroup, then execs ``argv``."""
        joins = " && ".join(f"echo $$ > {d / 'cgroup.procs'}" for d in self.dirs)
        return ["/bin/sh", "-c", f'{joins} && exec "$@"', "sh", *argv]

    def remove(self) -> None:
        """Remove the cgroup, and first any child cgroups (the testbed's
        per-program caps), moving what is left in them to the root."""
        for d in self.dirs:
            for c in cgroup_tree(d):  # children first; ``d`` itself last
                _remove_one(c, d.parent)


def _remove_one(d: Path, root: Path) -> None:
    """rmdir one cgroup once its processes are moved to ``root``."""
    for _ in range(50):
        try:
            for pid in (d / "cgroup.procs").read_text().split():
                try:
                    (root / "cgroup.procs").write_text(pid)
                except OSError:
                    pass
            d.rmdir()
            break
        except FileNotFoundError:
            break
        except OSError:
            time.sleep(0.05)
