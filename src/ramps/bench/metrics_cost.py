"""What serving Prometheus metrics costs an idle node (``ramps bench metrics``).

How this works: two real ``ramps node`` processes, each its own one-robot
team on loopback (``ramps.runtime.localteam``), run side by side for the
same seconds: one serves metrics and is scraped every ``scrape_every``
seconds over HTTP, the other does not. The CPU time each consumed (node
plus its idle workers, from psutil) over the window gives the cost as a
share of one core; running both at once makes the machine's noise hit both.
The CPU one render of ``/metrics`` takes is measured in-process too (a
``NodeMetrics`` with the series of a busy node: ``busy_metrics``), so the
cost at any scrape interval can be worked out: render CPU / interval.
"""

from __future__ import annotations

import time
import urllib.request

import psutil

from ramps.bench.teamsize import cpu_seconds, process_tree
from ramps.runtime.localteam import free_port
from ramps.runtime.metrics import NodeMetrics
from ramps.testing import LocalTeam


def _cpu(pid: int) -> float:
    """CPU seconds of process ``pid`` and its descendants."""
    return cpu_seconds(process_tree(pid))


def busy_metrics() -> NodeMetrics:
    """The metrics of a node that saw 5 hosts (r1-r5), 3 programs (prog0-prog2) and every outcome."""
    from ramps.core.events import Deliver, Note, StartProgram

    m = NodeMetrics("r1", "bench", cores=4, speed=1.0, policy="ramps")
    for i in range(200):
        host = f"r{i % 5 + 1}"
        pid = f"p{i}"
        m.on_action(Note(what="placed", program_id=pid, robot=host, attempt=1), None, i)
        m.on_action(Note(what="accepted", program_id=pid, robot=host, attempt=1), None, i + 0.01)
        m.on_action(Note(what="failed", program_id=pid, robot=host, attempt=1, detail="host_lost"), None, i + 1)
        m.on_action(StartProgram(program_id=pid, attempt=1, origin=host, program=f"prog{i % 3}", args=b"",
                                 work=1.0), None, i)
        m.on_action(Deliver(program_id=pid, ok=i % 4 != 0, error_kind="program", host=host), None, i + 2)
    m.on_report(cpu_busy=1.0, runnable=2.0, load_avg=1.0, mem_free=1 << 30, running=2, in_flight=3, sees=4,
                blacklisted=1, dropped=0, reports_received=100)
    return m


def render_cost(renders: int = 300) -> dict:
    """CPU seconds of one /metrics render of ``busy_metrics()``, and its size in bytes."""
    from prometheus_client import generate_latest

    m = busy_metrics()
    size = len(generate_latest(m.registry))
    t0 = time.process_time()
    for _ in range(renders):
        generate_latest(m.registry)
    per = (time.process_time() - t0) / renders
    return {"render_cpu_ms": per * 1e3, "bytes": size}


def measure_idle_cost(seconds: float = 60.0, scrape_every: float = 15.0, warmup: float = 5.0) -> dict:
    port = free_port()
    with_m = LocalTeam(1, cores=2, speed=1.0, env={**_env(), "RAMPS_METRICS": f"127.0.0.1:{port}"})
    without = LocalTeam(1, cores=2, speed=1.0, env=_env())
    url = f"http://127.0.0.1:{port}/metrics"
    try:
        with_m.start()
        without.start()
        time.sleep(warmup)
        pa, pb = with_m.procs["r1"].pid, without.procs["r1"].pid
        scrapes = 0
        a0, b0, t0 = _cpu(pa), _cpu(pb), time.monotonic()
        end = t0 + seconds
        next_scrape = t0
        while True:
            now = time.monotonic()
            if now >= end:
                break
            if now >= next_scrape:
                with urllib.request.urlopen(url, timeout=5) as resp:
                    resp.read()
                scrapes += 1
                next_scrape += scrape_every
            time.sleep(max(0.0, min(next_scrape, end) - time.monotonic()))
        wall = time.monotonic() - t0
        a, b = _cpu(pa) - a0, _cpu(pb) - b0
    finally:
        with_m.close()
        without.close()
    render = render_cost()
    return {
        "seconds": wall, "scrape_every_s": scrape_every, "scrapes": scrapes,
        "node_with_metrics_core_pct": 100 * a / wall, "node_without_metrics_core_pct": 100 * b / wall,
        "metrics_cost_core_pct": 100 * (a - b) / wall,
        "render_cpu_ms": render["render_cpu_ms"], "render_bytes": render["bytes"],
        "render_cost_at_15s_core_pct": render["render_cpu_ms"] / 1e3 / 15 * 100,
        "render_cost_at_1s_core_pct": render["render_cpu_ms"] / 1e3 / 1 * 100,
        "machine_cpus": psutil.cpu_count(),
    }


def _env() -> dict[str, str]:
    import os

    return {k: v for k, v in os.environ.items() if not k.startswith("RAMPS_")}


__all__ = ["busy_metrics", "measure_idle_cost", "render_cost"]
