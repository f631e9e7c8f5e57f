"""Relocation in a fleet: ``relocation.pool_bound`` an upper bound of
``host_times`` (what lets a check pass a crowded host's program over)."""

from __future__ import annotations

import random
from types import SimpleNamespace

from ramps.core.config import RampsConfig
from ramps.core.cost import program_share
from ramps.core.loadview import LoadView
from ramps.core.messages import LoadReport
from ramps.core.relocation import host_times, pool_bound


def view(seed: int, robots: int = 40) -> LoadView:
    """A view with fresh, old, lost, blacklisted, booked and sped-up robots."""
    rng = random.Random(seed)
    v = LoadView("me", cores=4, speed=1.0, max_report_age=10.0)
    for i in range(robots):
        name = f"r{i}"
        listed = sorted(rng.uniform(0.0, 50.0) for _ in range(rng.randrange(0, 5)))
        running = len(listed) + rng.randrange(0, 3)
        v.on_report(LoadReport(robot=name, incarnation=1, seq=1, cores=rng.choice([2, 4, 8]),
                               speed=rng.uniform(0.5, 2.0), cpu_busy=1.0, runnable=float(running + rng.randrange(0, 3)),
                               ramps_running=running, ramps_avg=float(running), accepted_total=running,
                               finished_total=0, remaining=listed, node_cpu=rng.choice([0.0, 0.3])),
                    rng.uniform(0.0, 20.0))
        if rng.random() < 0.3:
            v.book(name, f"p{i}", 1)
        if rng.random() < 0.2:
            v.speed_factor[name] = rng.uniform(0.5, 1.5)
        if rng.random() < 0.1:
            v.set_lost(name, True)
        if rng.random() < 0.1:
            v.blacklist(name)
    return v


def test_pool_bound_is_above_both_ends_host_times_gives() -> None:
    rng = random.Random(7)
    origin = SimpleNamespace(config=RampsConfig(place_by="pool_end"))
    checked = 0
    for seed in range(30):
        origin.view = view(seed)
        now = 16.0
        for row in origin.view.rows_and_best_rate(now)[0].values():
            host, cores, speed, ramps, bg, w = row
            if row[0] == "me":
                continue
            share = program_share(cores, max(1.0, ramps), bg, w)
            for _ in range(5):
                work = rng.uniform(1.0, 60.0)
                ap = SimpleNamespace(host=host, placed_host=host, work=work)
                left = rng.uniform(0.0, work)
                t_here, stay, _ = host_times(origin, ap, now, row, left)
                bound = pool_bound(origin, ap, row, left, share, {})
                assert bound >= t_here and bound >= stay
                checked += 1
    assert checked > 500
