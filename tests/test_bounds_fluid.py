"""``ramps.bench.simulator.fluid_bound``: a lower bound of the makespan with
release times, checked by hand on a small instance and against the exact
optimum (``ramps.experiments.optimum.exact_optimum``) on tiny ones."""

from __future__ import annotations

import random

import pytest

from ramps.bench.simulator import bounds, fluid_bound, large_team
from ramps.experiments.metrics import Machine
from ramps.experiments.optimum import exact_optimum


def test_idle_cores_before_a_late_burst_count() -> None:
    # one core of speed 1: 1 unit at 0, then 2 + 2 units at 5. All work over
    # the core: 5 s; the last release then alone: 7 s; the core is idle from
    # 1 to 5 whatever happens, so 5 + 4 = 9 s, the exact optimum.
    jobs = [(0.0, 1.0), (5.0, 2.0), (5.0, 2.0)]
    assert fluid_bound(jobs, speed=1.0, capacity=1.0) == pytest.approx(9.0)
    # two cores: the burst runs side by side, 5 + 2 = 7 s (the release bound)
    assert fluid_bound(jobs, speed=1.0, capacity=2.0) == pytest.approx(7.0)
    # one program on many cores still runs on one: 4 units at speed 2 take 2 s
    assert fluid_bound([(1.0, 4.0)], speed=2.0, capacity=100.0) == pytest.approx(3.0)
    assert fluid_bound([], speed=1.0, capacity=1.0) == 0.0


def test_never_above_the_exact_optimum_of_tiny_teams() -> None:
    rng = random.Random(7)
    tight = 0
    for _ in range(200):
        team = [Machine(cores=rng.choice((1, 2)), speed=rng.choice((1.0, 1.5))) for _ in range(rng.randint(1, 3))]
        releases = sorted(round(rng.uniform(0, 4), 1) for _ in range(rng.randint(1, 6)))
        work = 2.0
        best, proven, _ = exact_optimum(team, releases, work, upper=1e9)
        assert proven
        bound = fluid_bound([(r, work) for r in releases], max(m.speed for m in team),
                            sum(m.cores * m.speed for m in team))
        assert bound <= best + 1e-9, (team, releases, bound, best)
        tight += bound >= best - 1e-9
    assert tight > 0  # and it meets the optimum on some of them


def test_bounds_keep_the_old_figures_and_judge_by_the_largest() -> None:
    sc = large_team(robots=10, programs=200, origins=2)
    b = bounds(sc, makespan=300.0)
    assert b["capacity_bound"] == pytest.approx(200 * 53 / 40)
    assert b["release_bound"] == pytest.approx(1 + 99 * 0.01 + 53)
    assert b["fluid_bound"] >= max(b["capacity_bound"], b["release_bound"]) - 1e-9
    assert b["makespan_over_bound"] == pytest.approx(300.0 / b["fluid_bound"])
    assert b["makespan_over_release"] == pytest.approx(300.0 / max(b["capacity_bound"], b["release_bound"]))
