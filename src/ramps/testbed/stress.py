"""Stresses of a busy or half-dead robot, for ``ramps testbed campaign`` (issue 14).

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


# ====================================================================== many robots lost at once
def hearing_after_mass_loss(robots: int = 8, lose: int = 5, window: float = 9.0, how: str = "cut",
                            settle: float = 4.0, log=print) -> dict:
    """A testbed of ``robots`` (1 core each); ``lose`` of them (the last ones)
    are cut off (``how="cut"``: link down) or crashed at once. For ``window``
    seconds after, every survivor's trace of received messages (the nodes run
    with RAMPS_TRACE_WIRE) gives, per pair of survivors, the longest gap in
    hearing one another (Zenoh closing many links at once, SO_LINGER on a
    receive thread, can make survivors deaf for up to 10 s). Returns the
    gaps and the survivors' peer_lost events."""
    import json as _json

    from ramps.testbed import Testbed

    os.environ["RAMPS_TRACE_WIRE"] = "1"
    names = [f"r{i}" for i in range(1, robots + 1)]
    survivors, lost = names[:robots - lose], names[robots - lose:]

    def trace(tb, robot: str) -> list[dict]:
        try:
            return [_json.loads(x) for x in (tb.log_dir / f"{robot}.trace.jsonl").read_text().splitlines() if x]
        except OSError:
            return []

    with Testbed(names, cores=1) as tb:
        time.sleep(settle)
        t_cut = time.monotonic()
        for r in lost:
            (tb.cut if how == "cut" else tb.crash)(r)
        took = time.monotonic() - t_cut
        time.sleep(window)
        gaps: dict[str, float] = {}
        for rcv in survivors:
            tr = trace(tb, rcv)
            for snd in survivors:
                if snd == rcv:
                    continue
                heard = sorted(e["t"] for e in tr if e["what"] == "rx" and e["other"] == snd
                               and t_cut <= e["t"] <= t_cut + window)
                edges = [t_cut, *heard, t_cut + window]
                gaps[f"{snd}->{rcv}"] = round(max(b - a for a, b in zip(edges, edges[1:])), 3)
        wrongly_lost = sorted({f"{rcv} lost {e['other']}" for rcv in survivors for e in trace(tb, rcv)
                               if e["what"] == "peer_lost" and e["other"] in survivors})
    out = {"robots": robots, "lost": lose, "how": how, "window_s": window, "inject_s": round(took, 3),
           "max_gap_s": max(gaps.values()) if gaps else None, "gaps_s": gaps, "survivors_lost": wrongly_lost}
    log(f"{lose} of {robots} robots {how} at once (in {took:.2f} s): longest silence between survivors "
        f"{out['max_gap_s']} s; survivors written off by survivors: {wrongly_lost or 'none'}")
    return out


if __name__ == "__main__":  # python -m ramps.testbed.stress [ROBOTS LOSE cut|crash [OUT.json]]
    import json
    import sys

    a = sys.argv[1:]
    res = hearing_after_mass_loss(int(a[0]) if a else 8, int(a[1]) if len(a) > 1 else 5,
                                  how=a[2] if len(a) > 2 else "cut")
    if len(a) > 3:
        with open(a[3], "w") as f:
            json.dump(res, f, indent=1)
