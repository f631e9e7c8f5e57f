"""``ramps bench dispatch``: how fast the real team turns a call into a result.

How this works: three real ``ramps node`` processes on loopback (2 cores
each), one client. Latency: ``calls`` no-op programs one after another, each
timed from ``submit`` to the result in the caller's hands (so it includes
the client -> origin message, placement, the offload, the worker process,
the result and the outcome back); the ramps policy runs a lone no-op on the
origin itself, so offloads to another robot are timed separately (placed
round robin, only the calls that ran elsewhere). Throughput: ``burst`` no-op programs from
the same origin with up to ``window`` in flight. Figures are printed and
saved as JSON; nothing here asserts a target.

Wall-clock figures follow whatever else the machine runs; the CPU each
process spent per program of the burst (``burst_cpu_us``: the origin's node,
the other nodes, their workers, this client process) follows the code, so
a regression shows there even on a busy machine. The load average is saved
beside them (``loadavg``).
"""

from __future__ import annotations

import os
import statistics
import threading
import time
from collections import Counter

import psutil

from ramps.bench.simulator import machine
from ramps.testing import LocalTeam


def _cpu_seconds(procs: dict[str, psutil.Process]) -> dict[str, float]:
    """CPU seconds (user + system) each process has used, and its children
    (``<name>-workers``: a node's fork server and workers)."""
    out: dict[str, float] = {}
    for name, p in procs.items():
        try:
            t = p.cpu_times()
            out[name] = t.user + t.system
            if name != "client":
                kids = 0.0
                for c in p.children(recursive=True):
                    try:
                        ct = c.cpu_times()
                        kids += ct.user + ct.system
                    except psutil.Error:
                        continue
                out[f"{name}-workers"] = kids
        except psutil.Error:
            continue
    return out


def _pct(sorted_values: list[float], p: float) -> float:
    i = min(len(sorted_values) - 1, max(0, int(round(p / 100 * (len(sorted_values) - 1)))))
    return sorted_values[i]


def bench_dispatch(*, nodes: int = 3, calls: int = 1000, warmup: int = 100, burst: int = 5000,
                   window: int = 256, program: str = "noop") -> dict:
    with LocalTeam(nodes, cores=2, speed=1.0) as team:
        client = team.client()
        try:
            time.sleep(1.5)  # let every load server hear every robot once
            for _ in range(warmup):
                client.submit(program).result(timeout=30)
            lat = []
            lat_hosts: Counter = Counter()
            for _ in range(calls):
                t0 = time.perf_counter()
                f = client.submit(program)
                f.result(timeout=30)
                lat.append(time.perf_counter() - t0)
                lat_hosts[f.host] += 1
            lat.sort()
            # the ramps policy keeps a lone no-op on the origin (a tie goes to
            # the local robot); time offloads too, placed round robin, and keep
            # only the calls that ran on another robot
            remote = []
            for _ in range(calls):
                t0 = time.perf_counter()
                f = client.options(policy="round_robin").submit(program)
                f.result(timeout=30)
                if f.host != "r1":
                    remote.append(time.perf_counter() - t0)
            remote.sort()
            sem = threading.Semaphore(window)
            done = threading.Event()
            left = [burst]
            lock = threading.Lock()

            burst_hosts: Counter = Counter()

            def finished(f) -> None:
                burst_hosts[getattr(f, "host", "?")] += 1
                sem.release()
                with lock:
                    left[0] -= 1
                    if left[0] == 0:
                        done.set()

            procs = {"client": psutil.Process()}
            procs.update({name: psutil.Process(p.pid) for name, p in team.procs.items()})
            cpu0 = _cpu_seconds(procs)
            t0 = time.perf_counter()
            for _ in range(burst):
                sem.acquire()
                client.submit(program).add_done_callback(finished)
            done.wait(120)
            elapsed = time.perf_counter() - t0
            cpu1 = _cpu_seconds(procs)
        finally:
            client.close()
    return {
        "benchmark": "dispatch", "machine": machine(), "nodes": nodes, "program": program,
        "calls": calls, "p50_ms": _pct(lat, 50) * 1e3, "p90_ms": _pct(lat, 90) * 1e3,
        "p99_ms": _pct(lat, 99) * 1e3, "mean_ms": statistics.fmean(lat) * 1e3, "max_ms": lat[-1] * 1e3,
        "burst": burst, "window": window, "completed": burst - left[0], "throughput_per_s": (burst - left[0]) / elapsed,
        "latency_hosts": dict(lat_hosts), "remote_calls": len(remote),
        "remote_p50_ms": _pct(remote, 50) * 1e3, "remote_p99_ms": _pct(remote, 99) * 1e3, "burst_hosts": dict(burst_hosts),
        "burst_cpu_us": {name: (cpu1[name] - cpu0[name]) / max(1, burst - left[0]) * 1e6
                         for name in cpu1 if name in cpu0},
        "loadavg": list(os.getloadavg()),
    }
