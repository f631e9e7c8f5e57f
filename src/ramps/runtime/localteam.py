"""What a team of robots on one machine needs: free loopback ports, cpu
cgroups that make a process tree a small computer of a given number of host
cores (v1 or v2), and the rule for "every robot sees all the others".

Used by ``ramps.testing.LocalTeam`` (real node processes on loopback: the
demo, the benchmarks, the end-to-end tests) and by the testbed. The
``LocalTeam`` class itself moved to ``ramps.testing``.
"""

from __future__ import annotations

import os
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


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


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

    def __init__(self, name: str, quota: float, mode: str) -> None:
        self.mode = mode
        period = 100_000
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


def __getattr__(name: str) -> object:
    # LocalTeam lives in ramps.testing now (one harness for the demo, the
    # benchmarks and the tests); this name keeps older imports working
    if name == "LocalTeam":
        from ramps.testing import LocalTeam

        return LocalTeam
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
