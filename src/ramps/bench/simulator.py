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


def bounds(sc: Scenario, makespan: float) -> dict:
    """Lower bounds of the optimum's makespan for a ``large_team`` scenario,
    and the makespan over each: the capacity bound (all work over all
    cores) and the release bound (the last program submitted, run alone on
    a core from then). With many origins the release bound is the larger:
    origin i starts at second i, so the 100th submits its last program at
    109 s, which needs 53 s more wherever it runs."""
    team = sc.team()
    capacity = sum(p.count * p.work for p in sc.programs) / sum(r.cores * r.speed for r in team)
    fastest = max(r.speed for r in team)
    release = max(p.at + (p.count - 1) * p.spacing + p.work / fastest for p in sc.programs) - min(
        p.at for p in sc.programs)
    return {"capacity_bound": capacity, "release_bound": release, "makespan_over_capacity": makespan / capacity,
            "makespan_over_bound": makespan / max(capacity, release)}


def machine() -> dict:
    return {"python": platform.python_version(), "platform": platform.platform(), "cpus": os.cpu_count()}
