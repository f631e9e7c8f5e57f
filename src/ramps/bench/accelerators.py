"""``ramps bench accelerators``: a team with a real GPU, run through ramps.

How this works: a fresh team of real ``ramps node`` processes on loopback:
``r1`` and ``r2`` offer no accelerator (``RAMPS_ACCELERATORS=none``), ``g``
offers what NVML finds (``auto``: its NVIDIA GPUs, as ``cuda``), each with
``cores`` cores. From ``r1``, one client submits ``detects`` calls of
``ramps.programs.tensor:detect`` (matrix products with PyTorch, on the GPU
where its robot offers one, on one core elsewhere) and ``plans`` calls of
``burn`` (CPU only), all at once, after a warm-up burst of a few of each
(PyTorch's first CUDA call on a worker costs seconds). The same is then run
on the same kind of team with ``g``'s GPU switched off (``none``): every
program on CPUs. Printed and saved: the makespan of each, where each call
ran and on what device, the device seconds of the detects, and what ``g``'s
load reports said of its GPU (memory, utilisation) while it worked. Needs
``torch`` and ``nvidia-ml-py`` on the machine, and a GPU for the first run
to use one; as root with cpu cgroups, each node runs in a cgroup of its
cores, so it measures its own load (without, every node measures the whole
machine and CPU placement follows noise). Nothing here asserts a target.
"""

from __future__ import annotations

import statistics
import time
from collections import Counter
from typing import Any

from ramps.runtime.localteam import cgroup_mode
from ramps.testing import LocalTeam

DETECT = "ramps.programs.tensor:detect"


def _burst(team: Any, detects: int, plans: int, size: int, reps: int, plan_units: float,
           watch: Any = None) -> dict[str, Any]:
    """Submit the detects and plans at once; wait for all; what each did."""
    start = time.monotonic()
    futs = [("detect", team.submit("detect", size=size, reps=reps, seed=i)) for i in range(detects)]
    futs += [("burn", team.submit("burn", units=plan_units)) for _ in range(plans)]
    seen: list[dict[str, Any]] = []
    while any(not f.done() for _, f in futs):
        if watch is not None:
            seen.append(watch())
        time.sleep(0.25)
    makespan = time.monotonic() - start
    calls = []
    for kind, f in futs:
        value = f.result(0)
        calls.append({"program": kind, "host": f.host, "device": value.get("device", "cpu"),
                      "device_s": value.get("seconds")})
    where = Counter(f"{c['program']} on {c['host']} ({c['device']})" for c in calls)
    gpu_s = [c["device_s"] for c in calls if c["program"] == "detect" and c["device"].startswith("cuda")]
    cpu_s = [c["device_s"] for c in calls if c["program"] == "detect" and c["device"] == "cpu"]
    return {"makespan_s": round(makespan, 3), "where": dict(sorted(where.items())), "calls": calls,
            "detect_gpu_s_median": statistics.median(gpu_s) if gpu_s else None,
            "detect_cpu_s_median": statistics.median(cpu_s) if cpu_s else None,
            "gpu_seen": [s for s in seen if s]}


def _gpu_watch(team: Any) -> Any:
    def watch() -> dict[str, Any]:
        for r in team.status().robots:
            for a in r.accelerators:
                return {"robot": r.robot, "kind": a.kind, "slots": a.count, "programs": a.running,
                        "memory_free_gib": round(a.memory_free / 2**30, 2),
                        "memory_total_gib": round(a.memory_total / 2**30, 2), "utilisation": a.utilisation}
        return {}
    return watch


def bench_accelerators(*, detects: int = 12, plans: int = 12, size: int = 2048, reps: int = 10,
                       plan_units: float = 2.0, cores: int = 4) -> dict[str, Any]:
    """Both runs (the GPU offered, then not); see the module's docstring."""
    # each node in a cpu cgroup of its cores where the machine has them (root): it then measures its own
    # run queue, a GPU program's spinning worker included, not the whole machine's
    quota = float(cores) if cgroup_mode() is not None else None
    out: dict[str, Any] = {"detects": detects, "plans": plans, "size": size, "reps": reps,
                           "plan_units": plan_units, "cores": cores, "cgroups": quota is not None, "runs": {}}
    for label, offer in (("gpu offered", "auto"), ("cpu only", "none")):
        with LocalTeam(["r1", "r2"], cores=cores, programs=[DETECT], env={**_env(), "RAMPS_ACCELERATORS": "none"},
                       visible_timeout=60.0, cpu_quota=quota) as t:
            t.start_node("g", cores=cores, extra_env={"RAMPS_ACCELERATORS": offer}, timeout=60.0)
            team = t.client("r1")
            if offer == "auto":
                deadline = time.monotonic() + 30
                while not any(r.accelerators for r in team.status().robots) and time.monotonic() < deadline:
                    time.sleep(0.2)
            offered = [(r.robot, a.kind, a.count) for r in team.status().robots for a in r.accelerators]
            warm = _burst(team, min(3, detects), min(3, plans), size, reps, plan_units)
            run = _burst(team, detects, plans, size, reps, plan_units, watch=_gpu_watch(team))
            run["offered"] = offered
            run["warm_up_makespan_s"] = warm["makespan_s"]
            out["runs"][label] = run
    gpu, cpu = out["runs"]["gpu offered"], out["runs"]["cpu only"]
    out["speedup"] = round(cpu["makespan_s"] / gpu["makespan_s"], 2) if gpu["makespan_s"] else None
    return out


def _env() -> dict[str, str]:
    import os

    return dict(os.environ)
