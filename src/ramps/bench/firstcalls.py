"""``ramps bench first-calls``: how fast a fresh team runs a heavy program's first calls.

How this works: a fresh team of ``nodes`` real ``ramps node`` processes on
loopback (``cores`` each, as ``ramps bench dispatch``), one client. The
program (``route_plan`` by default: OR-Tools' CP-SAT, whose import costs
about a CPU-second) is called ``calls`` times with different seeds, in three
phases on the same team, each call timed from ``submit`` to its result:

    cold, at once:          the team's first calls, all submitted together
    warm, one after another the same calls, each after the last one's result
    warm, at once           the same calls, all submitted together again

The figures that matter are the cold burst's median over the one-after-another
median, and over the warm burst's (the same calls at once, on workers that
have run them): the executor's fork server imports every program's module,
and the modules a program declares in ``preload``, before it forks a worker,
so a fresh team's first calls pay no import, and a cold burst is no slower
than a warm one; what is left of the first ratio is the calls sharing the
cores. Memory: the resident (RSS),
proportional (PSS: shared pages divided among their users) and unique (USS)
memory of each node's fork server and its idle workers, right after the team
started and again after the calls (once the extra workers retired). Rounds
repeat everything on a fresh team. Figures are printed and saved as JSON;
nothing here asserts a target.
"""

from __future__ import annotations

import statistics
import threading
import time

import psutil

from ramps.bench.simulator import machine
from ramps.runtime.workers import RETIRE_AFTER
from ramps.testing import LocalTeam

MB = 1 << 20


def _at_once(client, program: str, calls: int, kwargs: dict) -> tuple[list[float], list[str]]:
    """Submit ``calls`` programs together; each one's seconds from its submit to its result."""
    lat: list[float] = [0.0] * calls
    hosts: list[str] = [""] * calls
    done = threading.Semaphore(0)
    futs = []
    for i in range(calls):
        t0 = time.perf_counter()
        fut = client.submit(program, seed=i, **kwargs)

        def finished(f, i=i, t0=t0) -> None:
            lat[i] = time.perf_counter() - t0
            hosts[i] = f.host
            done.release()

        fut.add_done_callback(finished)
        futs.append(fut)
    for _ in range(calls):
        done.acquire(timeout=300)
    for fut in futs:
        fut.result(timeout=1)  # a failed call fails the benchmark
    return lat, hosts


def _one_after_another(client, program: str, calls: int, kwargs: dict) -> tuple[list[float], list[str]]:
    lat, hosts = [], []
    for i in range(calls):
        t0 = time.perf_counter()
        fut = client.submit(program, seed=i, **kwargs)
        fut.result(timeout=300)
        lat.append(time.perf_counter() - t0)
        hosts.append(fut.host)
    return lat, hosts


def _mem(proc: psutil.Process) -> dict:
    m = proc.memory_full_info()
    return {"rss_mb": m.rss / MB, "pss_mb": getattr(m, "pss", 0) / MB, "uss_mb": m.uss / MB}


def executor_memory(team: LocalTeam) -> dict:
    """Each robot's node, fork server and workers: RSS, PSS and USS in MB
    (and the fork server's CPU seconds so far: its start, preload included)."""
    robots = {}
    for name, node in team.nodes.items():
        proc = psutil.Process(node.pid)
        entry: dict = {"node": _mem(proc), "fork_server": None, "workers": []}
        for child in proc.children():
            try:
                if "--fork-server" not in child.cmdline():
                    continue
                entry["fork_server"] = _mem(child)
                cpu = child.cpu_times()
                entry["fork_server"]["cpu_s"] = cpu.user + cpu.system
                entry["workers"] = [_mem(w) for w in child.children()]
            except psutil.Error:
                continue
        ws = entry["workers"]
        entry["executor_pss_mb"] = ((entry["fork_server"] or {}).get("pss_mb", 0.0)
                                    + sum(w["pss_mb"] for w in ws))
        robots[name] = entry
    return robots


def _phase(lat: list[float], hosts: list[str]) -> dict:
    s = sorted(lat)
    return {"ms": [x * 1e3 for x in lat], "p50_ms": statistics.median(s) * 1e3, "max_ms": s[-1] * 1e3,
            "min_ms": s[0] * 1e3, "hosts": hosts}


def bench_first_calls(*, nodes: int = 3, cores: int = 2, calls: int = 6, rounds: int = 1,
                      program: str = "route_plan", picks: int = 8) -> dict:
    """``program`` takes ``seed`` (call i gets seed i) and, for route_plan, ``picks``."""
    kwargs = {"picks": picks} if program == "route_plan" else {}
    results = []
    for _ in range(rounds):
        t0 = time.perf_counter()
        with LocalTeam(nodes, cores=cores, speed=1.0) as team:
            started_s = time.perf_counter() - t0
            client = team.client()
            time.sleep(1.5)  # let every load server hear every robot once
            mem_start = executor_memory(team)
            cold = _phase(*_at_once(client, program, calls, kwargs))
            seq = _phase(*_one_after_another(client, program, calls, kwargs))
            warm = _phase(*_at_once(client, program, calls, kwargs))
            time.sleep(RETIRE_AFTER + 1.5)  # workers beyond the cores retire
            mem_after = executor_memory(team)
        results.append({"team_start_s": started_s, "cold_at_once": cold, "warm_one_after_another": seq,
                        "warm_at_once": warm, "cold_over_sequential_p50": cold["p50_ms"] / seq["p50_ms"],
                        "cold_over_warm_at_once_p50": cold["p50_ms"] / warm["p50_ms"],
                        "memory_start": mem_start, "memory_after": mem_after})
    def spread(key: str) -> dict:
        xs = [r[key] for r in results]
        return {"median": statistics.median(xs), "min": min(xs), "max": max(xs)}

    return {"benchmark": "first-calls", "machine": machine(), "nodes": nodes, "cores": cores, "calls": calls,
            "program": program, "kwargs": kwargs, "rounds": results,
            "cold_over_sequential_p50": spread("cold_over_sequential_p50"),
            "cold_over_warm_at_once_p50": spread("cold_over_warm_at_once_p50")}
