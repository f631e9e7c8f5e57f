"""Stresses of a busy or half-dead robot: what ``ramps testbed campaign`` injects.

How this works: besides the whole-robot faults of ``Testbed`` (crash: SIGKILL
of everything; cut: link down; freeze: SIGSTOP of everything), a real robot
fails by halves:

* ``stall_node``: only the node process stops (SIGSTOP), its workers run on:
  a node starved of CPU, in a long pause, or stopped by a debugger.
  ``Testbed.recover`` continues it (it is recorded as ``frozen``).
* ``crash_node``: only the node process is killed (SIGKILL), not its process
  group: its fork server and workers must go with it at once. Returns what
  of the robot is still running 1 s later besides its busy load (orphans);
  ``Testbed.recover`` restarts the node (recorded as ``crashed``).
* host CPU pressure: ``Testbed.add_load``/``remove_load`` (busy processes
  inside the robot's cgroup, appearing and vanishing).

``orphans`` lists a robot's processes that are neither its node, nor the
node's descendants (fork server, workers), nor its busy load: work that
nobody will collect.
"""

from __future__ import annotations

import os
import signal
import time

from ramps.testbed.procs import _alive, _cgroup_pids


def _descendants(pid: int) -> set[int]:
    import psutil

    try:
        return {p.pid for p in psutil.Process(pid).children(recursive=True)}
    except psutil.Error:
        return set()


def orphans(tb, robot: str) -> list[int]:
    """Live processes of ``robot`` that belong to no running node and are not its load."""
    rb = tb.robots[robot]
    load = {p for p, s in rb["load_pids"] if _alive(p, s) != "dead"}
    node = {rb["pid"]} | _descendants(rb["pid"]) if rb["pid"] and _alive(rb["pid"], rb["start"]) != "dead" else set()
    out = []
    for pid in _cgroup_pids(rb["cgroup"]):
        if pid in load or pid in node:
            continue
        try:
            with open(f"/proc/{pid}/stat") as f:
                state = f.read().rsplit(")", 1)[1].split()[0]
        except OSError:
            continue
        if state != "Z":
            out.append(pid)
    return sorted(out)


def stall_node(tb, robot: str) -> None:
    """SIGSTOP the robot's node process alone (its workers keep running)."""
    with tb._lock:
        tb._live()
        rb = tb._robot(robot)
        if "crashed" in rb["faults"] or not rb["pid"]:
            return
        try:
            os.kill(rb["pid"], signal.SIGSTOP)
        except ProcessLookupError:
            return
        if "frozen" not in rb["faults"]:
            rb["faults"].append("frozen")  # recover() sends SIGCONT
        tb._save()


def crash_node(tb, robot: str, settle: float = 1.0) -> list[int]:
    """SIGKILL the robot's node process alone; return the robot's orphans
    ``settle`` seconds later (none: its workers died with it)."""
    with tb._lock:
        tb._live()
        rb = tb._robot(robot)
        if "crashed" in rb["faults"] or not rb["pid"] or _alive(rb["pid"], rb["start"]) == "dead":
            return []
        pid = rb["pid"]
        try:
            os.kill(pid, signal.SIGKILL)
            os.kill(pid, signal.SIGCONT)  # if it was stalled
        except ProcessLookupError:
            pass
        rb["faults"] = [f for f in rb["faults"] if f != "frozen"] + ["crashed"] * ("crashed" not in rb["faults"])
        tb._save()
    deadline = time.monotonic() + settle
    left = orphans(tb, robot)
    while left and time.monotonic() < deadline:
        time.sleep(0.05)
        left = orphans(tb, robot)
    tb.procs.reap()
    return left
