"""The exact optimum of several-origins scenarios (ramps.experiments.optimum)
against brute force on small teams, and the assumption its bound rests on."""

from __future__ import annotations

import itertools
import random

import pytest

from ramps.experiments.metrics import Machine, finish_time
from ramps.experiments.optimum import exact_optimum, finish
from ramps.experiments.sweep import generate, lower_bound, machines, oracle, releases

W = 53.0


def test_finish_is_processor_sharing():
    m = Machine(cores=4, speed=1.0, background=0)
    assert finish(m, [0.0] * 4, W) == pytest.approx(W)
    assert finish(m, [0.0] * 6, W) == pytest.approx(finish_time(m, 6, W))
    assert finish(Machine(4, 2.0, 4), [0.0] * 4, W) == pytest.approx(finish_time(Machine(4, 2.0, 4), 4, W))
    # one program alone, then a second 10 s later: both get a core
    assert finish(m, [0.0, 10.0], W) == pytest.approx(10.0 + W)
    assert finish(m, [], W) == 0.0


def _random_machine(rng: random.Random) -> Machine:
    return Machine(rng.choice((1, 2, 4)), rng.choice((0.5, 1.0, 2.0)), rng.choice((0, 0, 2, 4)))


def test_what_the_search_bound_assumes():
    """A robot never ends earlier with more programs, nor when the programs
    still to come are all released at the first of their release times
    or earlier (after those it has). Neither is proven here, only checked: releasing one
    program earlier *can* make a robot end later (the last test)."""
    rng = random.Random(7)
    for _ in range(3000):
        m = _random_machine(rng)
        placed = sorted(rng.uniform(0, 10) for _ in range(rng.randint(0, 5)))
        first = rng.uniform(max(placed, default=0.0), 15)
        rest = sorted([first] + [rng.uniform(first, 25) for _ in range(rng.randint(0, 4))])
        at = rng.uniform(max(placed, default=0.0), first)  # the next release of the whole scenario
        assert finish(m, placed + [at] * len(rest), W) <= finish(m, placed + rest, W) + 1e-6
        assert finish(m, placed, W) <= finish(m, sorted(placed + rest), W) + 1e-6
    # the property that does not hold, and which the bound does not use
    m = Machine(4, 1.0, 2)
    rel = [2.3613155650992423, 3.0396906932100953, 8.362456435704544, 15.142818591304987, 19.603496949851642]
    moved = sorted(rel[:3] + [6.385701682093164] + rel[4:])
    assert finish(m, moved, W) > finish(m, rel, W) + 0.4


def _brute_force(team, rel) -> float:
    best = float("inf")
    for assignment in itertools.product(range(len(team)), repeat=len(rel)):
        per = [[r for r, a in zip(rel, assignment) if a == i] for i in range(len(team))]
        best = min(best, max(finish(m, p, W) for m, p in zip(team, per)))
    return best


def test_the_search_finds_what_brute_force_finds():
    rng = random.Random(3)
    for _ in range(40):
        team = [_random_machine(rng) for _ in range(rng.randint(2, 3))]
        rel = sorted(rng.choice((0.0, rng.uniform(0, 10))) for _ in range(rng.randint(1, 6)))
        upper = _brute_force(team, rel) * 1.5 + 1.0
        best, proven, _ = exact_optimum(team, rel, W, upper)
        assert proven
        assert best == pytest.approx(_brute_force(team, rel))


def test_between_the_lower_bound_and_the_oracle_on_generated_scenarios():
    for index in range(4):
        sc = generate("mixed", "staggered", index, 0)
        orc, _ = oracle(sc)
        best, proven, nodes = exact_optimum(machines(sc), releases(sc), W, orc, max_nodes=20_000)
        assert lower_bound(sc) - 1e-6 <= best <= orc + 1e-9
        assert nodes <= 20_001


def test_a_search_out_of_budget_proves_nothing():
    sc = generate("idle", "staggered", 10, 0)  # 54 programs on 11 robots
    orc, _ = oracle(sc)
    best, proven, nodes = exact_optimum(machines(sc), releases(sc), W, orc, max_nodes=50)
    assert not proven and nodes == 51 and best <= orc


def test_the_sweep_reports_the_optimum_where_it_is_known():
    from ramps.experiments.sweep import run_scenario

    sc = generate("mixed", "staggered", 0, 0)  # 3 robots, 3 origins, 7 programs
    found = run_scenario(sc, policy="ramps", seeds=1, seed=0, exact_nodes=50_000)
    assert found.optimum is not None and found.lower_bound <= found.optimum <= found.oracle
    assert found.ratio_optimum == pytest.approx(found.runs[0].makespan / found.optimum)
    assert run_scenario(sc, policy="ramps", seeds=1, seed=0).optimum is None  # no search: open
    burst = run_scenario(generate("idle", "burst", 0, 0), policy="ramps", seeds=1, seed=0)
    assert burst.optimum == burst.lower_bound  # the oracle reaches the bound
