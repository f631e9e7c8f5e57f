"""The testbed's processes and cgroups, by pid and path.

How this works: a testbed records each process it starts as (pid, start
time in clock ticks, from ``/proc/<pid>/stat``), so a pid the kernel has
reused is never taken for ours (``_alive``); a robot's processes are the
members of its cpu cgroup and of the per-program cgroups under it
(``_cgroup_pids``); ``_cgroup`` is a handle on a cgroup that exists already
(``RobotCgroup()`` would create it). The nodes get a clean environment:
their settings come from their command line, not the caller's ``RAMPS_*``.
``RobotRecord`` is one robot as the testbed and its state file hold it.

Used by ``ramps.testbed.bed`` (lifecycle), ``ramps.testbed.faults``,
``ramps.testbed.cleanup`` and the measuring tools (stress, fidelity); ``TestbedError`` lives here so all
of them can raise it.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, TypedDict

from ramps.errors import RampsError
from ramps.runtime.localteam import RobotCgroup
from ramps.runtime.measure import cgroup_tree, proc_stat_fields


class TestbedError(RampsError):
    """A testbed cannot be built, found or driven (no testbed up, unknown robot, ...)."""

    __test__ = False  # not a pytest test class


class RobotRecord(TypedDict):
    """One robot of a testbed (``Testbed.robots``; ``robots`` in its state file)."""

    name: str
    #: its place in the testbed, from 1: the last byte of its address
    index: int
    ip: str
    #: its network namespace
    ns: str
    #: the host's end of its veth pair
    veth: str
    #: its cpu cgroup's directories (one on v2; cpu and cpuacct on v1)
    cgroup: list[str]
    #: its node's process and that process's start time (``_proc_stat``); None before it starts
    pid: int | None
    start: int | None
    #: how many busy processes load it, and each one's (pid, start time)
    load: int
    load_pids: list[tuple[int, int | None]]
    #: the faults it is under: "crashed", "cut", "frozen", "lossy"
    faults: list[str]


def robot_record(saved: dict[str, Any]) -> RobotRecord:
    """A ``RobotRecord`` read back from a state file (JSON has no tuples)."""
    return RobotRecord(name=saved["name"], index=saved["index"], ip=saved["ip"], ns=saved["ns"], veth=saved["veth"],
                       cgroup=list(saved["cgroup"]), pid=saved["pid"], start=saved["start"], load=saved["load"],
                       load_pids=[(pid, start) for pid, start in saved["load_pids"]], faults=list(saved["faults"]))


def _proc_stat(pid: int) -> tuple[str, int] | None:
    """(state letter, start time in ticks) of a process, or None if gone."""
    rest = proc_stat_fields(pid)
    return None if rest is None else (rest[0], int(rest[19]))


def _alive(pid: int | None, start: int | None) -> str:
    """'running', 'stopped' or 'dead' for a pid recorded with its start time."""
    if not pid:
        return "dead"
    st = _proc_stat(pid)
    if st is None or st[0] in ("Z", "X") or (start is not None and st[1] != start):
        return "dead"
    return "stopped" if st[0] in ("T", "t") else "running"


def _cgroup_pids(dirs: list[str]) -> list[int]:
    """Every process in these cgroups and their children (the per-program
    cgroups of ``ramps.testbed.caps``)."""
    pids: set[int] = set()
    for d in dirs:
        for sub in cgroup_tree(d):
            try:
                pids.update(int(p) for p in (sub / "cgroup.procs").read_text().split())
            except OSError:
                pass
    return sorted(pids)


def _signal_all(pids: list[int], sig: int) -> None:
    for pid in pids:
        try:
            os.kill(pid, sig)
        except (ProcessLookupError, PermissionError):
            pass


def _cgroup(dirs: list[str], mode: str) -> RobotCgroup:
    """A handle on an existing robot cgroup (RobotCgroup() would create it)."""
    cg = RobotCgroup.__new__(RobotCgroup)
    cg.mode = mode
    cg.dirs = [Path(d) for d in dirs]
    return cg


def _clean_env() -> dict[str, str]:
    # the nodes get their settings from the command line, not from this shell;
    # RAMPS_TRACE_WIRE passes, to chase delays between robots in their traces
    env = {k: v for k, v in os.environ.items() if not k.startswith("RAMPS_") or k == "RAMPS_TRACE_WIRE"}
    src = str(Path(__file__).resolve().parents[2])  # src layout: keep `ramps` importable as in this process
    env["PYTHONPATH"] = src + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    return env
