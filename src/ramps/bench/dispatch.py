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

Against earlier code: ``compare`` sets a run's figures beside a saved
baseline's (``BASELINES``: the same measurement of fe693da, the last code
at full speed, and of the release 0.1.0, on the development VM), as ratios;
``measure_code`` runs this same measurement on another checkout of ramps
(its ``src`` on ``PYTHONPATH``, in a process of its own: this file runs as
a script there, and imports nothing of ramps that old code lacks), so
that two codes can be measured in turns on the same machine at the same
time, the only comparison of wall-clock figures that holds on a shared
machine.
"""

from __future__ import annotations

import json
import os
import platform
import statistics
import subprocess
import sys
import threading
import time
from collections import Counter
from pathlib import Path
from typing import Any

import psutil

#: saved baselines, by name: the same measurement of earlier code (see the module docstring)
BASELINES = {name: Path(__file__).with_name(f"dispatch-baseline-{name}.json") for name in ("fe693da", "0.1.0")}
#: the figures ``compare`` sets beside a baseline's, and whether more is better
COMPARED = {"p50_ms": False, "remote_p50_ms": False, "throughput_per_s": True, "cpu_us": False}


def _local_team() -> Any:
    try:
        from ramps.testing import LocalTeam
    except ImportError:  # ramps of 2026-11-21 (fe693da) kept it in the runtime
        from ramps.runtime.localteam import LocalTeam  # type: ignore[no-redef,attr-defined]
    return LocalTeam


def _machine() -> dict[str, Any]:
    return {"python": platform.python_version(), "platform": platform.platform(), "cpus": os.cpu_count()}


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
    """Long because it is one measurement in three phases (one at a time on the origin, offloaded, a
    burst), each timed in line so that nothing but the calls runs between the clock readings."""
    import ramps

    with _local_team()(nodes, cores=2, speed=1.0) as team:
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
        "benchmark": "dispatch", "machine": _machine(), "nodes": nodes, "program": program,
        "code": {"ramps": getattr(ramps, "__version__", "?"), "path": str(Path(ramps.__file__).parent)},
        "calls": calls, "p50_ms": _pct(lat, 50) * 1e3, "p90_ms": _pct(lat, 90) * 1e3,
        "p99_ms": _pct(lat, 99) * 1e3, "mean_ms": statistics.fmean(lat) * 1e3, "max_ms": lat[-1] * 1e3,
        "burst": burst, "window": window, "completed": burst - left[0], "throughput_per_s": (burst - left[0]) / elapsed,
        "latency_hosts": dict(lat_hosts), "remote_calls": len(remote),
        "remote_p50_ms": _pct(remote, 50) * 1e3, "remote_p99_ms": _pct(remote, 99) * 1e3, "burst_hosts": dict(burst_hosts),
        "burst_cpu_us": {name: (cpu1[name] - cpu0[name]) / max(1, burst - left[0]) * 1e6
                         for name in cpu1 if name in cpu0},
        "loadavg": list(os.getloadavg()),
    }


def measure_code(checkout: str | os.PathLike[str], **kwargs: Any) -> dict:
    """``bench_dispatch`` of the ramps in ``checkout`` (a source tree: its
    ``src``, or itself, goes first on ``PYTHONPATH``), in a process of its
    own; its git commit, if it is a git checkout, is saved as ``code.commit``."""
    root = Path(checkout).resolve()
    src = root / "src" if (root / "src" / "ramps").is_dir() else root
    if not (src / "ramps").is_dir():
        raise ValueError(f"{checkout} holds no ramps source (no ramps/ or src/ramps/ in it)")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [str(src), os.environ.get("PYTHONPATH", "")])))
    run = f"import runpy, sys; sys.argv[1:] = [{json.dumps(kwargs)!r}]; runpy.run_path({__file__!r}, run_name='__main__')"
    proc = subprocess.run([sys.executable, "-c", run], env=env, cwd=root, capture_output=True, text=True, timeout=900)
    lines = proc.stdout.strip().splitlines()
    if proc.returncode != 0 or not lines:
        raise RuntimeError(f"the measurement of {checkout} failed: {proc.stderr.strip()[-2000:]}")
    res = json.loads(lines[-1])
    commit = subprocess.run(["git", "-C", str(root), "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
    if commit.returncode == 0:
        res["code"]["commit"] = commit.stdout.strip()
    return res


def figures(res: dict) -> dict[str, float]:
    """The figures ``compare`` weighs: p50 at the origin and offloaded (ms),
    programs/s of the burst, and CPU per program of the burst, all processes (us)."""
    return {"p50_ms": res["p50_ms"], "remote_p50_ms": res["remote_p50_ms"],
            "throughput_per_s": res["throughput_per_s"], "cpu_us": sum(res.get("burst_cpu_us", {}).values())}


def compare(res: dict, baseline: dict) -> dict[str, dict[str, float]]:
    """Each figure of ``res`` beside the baseline's (a saved run, or the
    median of its ``runs``), and their ratio: above 1 is better for
    programs/s, below 1 for the others (``COMPARED``)."""
    base = baseline_figures(baseline)
    ours = figures(res)
    return {k: {"this": ours[k], "baseline": base[k], "ratio": ours[k] / base[k] if base[k] else float("nan"),
                "better": (ours[k] >= base[k]) == more} for k, more in COMPARED.items()}


def baseline_figures(baseline: dict) -> dict[str, float]:
    """A baseline's figures: of its one run, or the median of its ``runs``."""
    runs = baseline.get("runs") or [baseline]
    each = [figures(r) for r in runs]
    return {k: statistics.median(f[k] for f in each) for k in COMPARED}


def load_baseline(name_or_path: str) -> dict:
    """A saved baseline: one of ``BASELINES`` by name, or a JSON file."""
    path = BASELINES.get(name_or_path) or Path(name_or_path)
    return json.loads(Path(path).read_text())


if __name__ == "__main__":  # measure_code's process: the ramps on PYTHONPATH, this file as a script
    print(json.dumps(bench_dispatch(**json.loads(sys.argv[1]))))
