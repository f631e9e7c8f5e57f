"""Benchmarks of the simulator, with figures printed and saved as JSON.

Rules: benchmarks measure, tests assert; nothing here fails on a slow
machine. Each benchmark returns a plain dict of figures; the CLI prints it
and writes it to a JSON file.
"""

from __future__ import annotations

import os
import platform
import time
from collections import Counter
from typing import Sequence

from ramps.core.config import RampsConfig
from ramps.experiments.paper import run_experiment
from ramps.sim.engine import simulate
from ramps.sim.scenario import ProgramSpec, PublisherSpec, RobotSpec, Scenario


def large_team(robots: int = 1000, programs: int = 10_000, origins: int = 10, seed: int = 0,
               config: RampsConfig | None = None, report_period: float | None = None) -> Scenario:
    """A big team: ``origins`` robots each submit an equal share of programs
    (``config``: the team's core settings, the defaults without;
    ``report_period``: seconds between a robot's periodic load reports, the
    simulator's default without)."""
    per = programs // origins
    entries = [
        ProgramSpec(count=per + (1 if i < programs % origins else 0), work=53.0, payload=2000, result=1000,
                    origin=f"w{i + 1}", at=float(i), spacing=0.01)
        for i in range(origins)
    ]
    return Scenario(name=f"large-{robots}r-{programs}p", seed=seed,
                    robots=[RobotSpec(name="w{i}", count=robots, cores=4, speed=1.0)], programs=entries,
                    config=config or RampsConfig(),
                    publisher=PublisherSpec() if report_period is None else PublisherSpec(period=report_period))


def bench_sweep(runs: int = 3, policy: str = "ramps") -> dict:
    started = time.perf_counter()
    out: dict[str, object] = {}
    for experiment in ("unloaded", "loaded"):
        rep = run_experiment(experiment, policy=policy, runs=runs)
        out[experiment] = {"wall_seconds": rep.wall_seconds, "optimal_or_near_share": rep.summary.optimal_or_near_share,
                           "simulations": len(rep.configs) * runs * 3}
    out["wall_seconds"] = time.perf_counter() - started
    return out


def bench_large(robots: int = 1000, programs: int = 10_000, origins: int = 10, policy: str = "ramps",
                config: RampsConfig | None = None, report_period: float | None = None) -> dict:
    """One ``large_team`` run timed (wall and this process's CPU seconds), its
    makespan against ``bounds``, and how evenly the robots were loaded."""
    sc = large_team(robots, programs, origins, config=config, report_period=report_period)
    started, cpu = time.perf_counter(), time.process_time()
    res = simulate(sc, policy=policy)
    wall, cpu = time.perf_counter() - started, time.process_time() - cpu
    default = RampsConfig()
    changed = {name: getattr(sc.config, name) for name in sc.config.__struct_fields__
               if getattr(sc.config, name) != getattr(default, name)}
    return {**bounds(sc, res.makespan),
        "robots": robots, "programs": programs, "origins": origins, "policy": policy, "config": changed,
        "report_period": sc.publisher.period,
        "wall_seconds": wall, "cpu_seconds": cpu, "completed": res.completed, "lost": res.lost,
        "duplicated": res.duplicated, "makespan_virtual_s": res.makespan, "events": res.events,
        "events_per_s": res.events / wall if wall else 0, "messages_sent": res.messages_sent,
        "rejections": sum(s.rejections for s in res.statistics),
        "robots_by_programs": {str(k): v for k, v in sorted(Counter(res.distribution.values()).items())},
    }


def fluid_bound(jobs: Sequence[tuple[float, float]], speed: float, capacity: float) -> float:
    """A lower bound of any schedule's makespan of ``jobs`` ((release time,
    work units) pairs) on cores of at most ``speed`` work units a second
    each, ``capacity`` work units a second in all: even if a program could
    move, split its time between cores and never wait, it runs on one core
    at a time, so by any time s it has done at most ``max(0, s - r) *
    speed`` of its work, and what is left, R(s), needs R(s) / capacity more
    seconds of the whole team. The bound is the largest ``s + R(s) /
    capacity``; it is at least the capacity bound (s = the first release)
    and the release bound (s = the last ``r + work / speed``). R is
    piecewise linear with its breakpoints at each r and r + work / speed,
    so the largest value is at one of them: one sweep over them in time
    order."""
    if not jobs:
        return 0.0
    change: dict[float, int] = {}  # at each breakpoint: programs that start or stop losing work
    for r, w in jobs:
        change[r] = change.get(r, 0) + 1
        end = r + w / speed
        change[end] = change.get(end, 0) - 1
    left, active, best = float(sum(w for _, w in jobs)), 0, 0.0
    prev = min(change)
    for t in sorted(change):
        left = max(0.0, left - active * speed * (t - prev))
        best, prev = max(best, t + left / capacity), t
        active += change[t]
    return best


def bounds(sc: Scenario, makespan: float) -> dict:
    """Lower bounds of the optimum's makespan for a ``large_team`` scenario,
    and the makespan over each: the capacity bound (all work over all
    cores), the release bound (the last program submitted, run alone on a
    core from then) and ``fluid_bound``, at least both. With many origins
    the release bound is larger than the capacity bound: origin i starts at
    second i, so the 100th submits its last program at 109 s, which needs
    53 s more wherever it runs. Release times are counted from the first
    ``at``, jittered ones at their earliest."""
    team = sc.team()
    cores = sum(r.cores * r.speed for r in team)
    capacity = sum(p.count * p.work for p in sc.programs) / cores
    fastest = max(r.speed for r in team)
    t0 = min(p.at for p in sc.programs)
    release = max(p.at + (p.count - 1) * p.spacing + p.work / fastest for p in sc.programs) - t0
    fluid = fluid_bound([(max(0.0, p.at + i * p.spacing - p.jitter) - t0 if p.jitter else p.at + i * p.spacing - t0,
                          p.work) for p in sc.programs for i in range(p.count)], fastest, cores)
    best = max(capacity, release, fluid)
    return {"capacity_bound": capacity, "release_bound": release, "fluid_bound": fluid,
            "makespan_over_capacity": makespan / capacity, "makespan_over_release": makespan / max(capacity, release),
            "makespan_over_bound": makespan / best}


def machine() -> dict:
    return {"python": platform.python_version(), "platform": platform.platform(), "cpus": os.cpu_count()}
