"""The exact optimum of several-origins scenarios (ramps.experiments.optimum)
against brute force on small teams, and the assumption its bound rests on."""

from __future__ import annotations

import itertools
import random

import pytest

from ramps.experiments.metrics import Machine, finish_time
from ramps.experiments.optimum import anneal, exact_optimum, finish, improve, makespan_of, solve
from ramps.experiments.optimum_bounds import shared_window_end, simple_bound, window_bound, window_end
from ramps.experiments.optimum_online import online_bound, online_limit
from ramps.experiments.sweep import generate, lower_bound, machines, oracle, oracle_schedule, releases

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


def test_a_window_end_is_never_after_the_robot_ends():
    """The window bound's robot: programs released in [t1, t2) with at least
    work - (t2 - t1) * speed left at t2, and those released at or after t2
    as if released at t2, end no later than the robot really does (this
    uses the two properties above and a third: less work left never ends
    later; checked, not proven)."""
    rng = random.Random(11)
    for _ in range(3000):
        m = _random_machine(rng)
        rel = sorted(rng.uniform(0, 12) for _ in range(rng.randint(1, 9)))
        t1, t2 = sorted(rng.sample([0.0] + rel, 2))
        x = sum(1 for r in rel if t1 <= r < t2)
        y = sum(1 for r in rel if r >= t2)
        assert window_end(m, x, W - (t2 - t1) * m.speed, y, t2, W) <= finish(m, rel, W) + 1e-6


def test_a_shared_window_end_is_never_after_the_robot_ends_and_never_below_window_end():
    """The same robot, knowing also that the window's programs shared it: together
    they did at most x * rate(m, x) a second (see ``shared_window_end``)."""
    rng = random.Random(12)
    stronger = 0
    for _ in range(3000):
        m = _random_machine(rng)
        rel = sorted(rng.choice((rng.uniform(0, 12), rng.uniform(0, 1), 5.0)) for _ in range(rng.randint(1, 12)))
        t1, t2 = sorted(rng.sample([0.0] + rel, 2))
        x = sum(1 for r in rel if t1 <= r < t2)
        y = sum(1 for r in rel if r >= t2)
        new = shared_window_end(m, x, t2 - t1, y, t2, W)
        assert new <= finish(m, rel, W) + 1e-6
        old = window_end(m, x, W - (t2 - t1) * m.speed, y, t2, W)
        assert new >= old - 1e-9
        stronger += new > old + 1e-6
    assert stronger > 1000  # crowded and loaded robots: most of them


def test_a_shared_window_end_by_hand():
    m = Machine(cores=2, speed=1.0, background=0)
    # 4 programs in the 8 s before t2 = 8: together at most 2 cores x 8 s = 16 units done, 4 each
    assert shared_window_end(m, 4, 8.0, 0, 8.0, W) == pytest.approx(8.0 + (W - 4.0) / 0.5)
    # with one more at 8: each has at least W - 8 = 45 left, and the other 16 units spread as
    # flat as can be over levels [45, 53) are 2 of the 4 programs: all 5 share to 45, then 3 to 53
    assert shared_window_end(m, 4, 8.0, 1, 8.0, W) == pytest.approx(8.0 + 45 / 0.4 + 8 / (2 / 3))
    assert shared_window_end(m, 4, 8.0, 1, 8.0, W) <= finish(m, [0.0] * 4 + [8.0], W) + 1e-9
    # two on two cores did not share: as window_end
    assert shared_window_end(m, 2, 8.0, 1, 8.0, W) == pytest.approx(window_end(m, 2, W - 8.0, 1, 8.0, W))


def test_window_end_is_processor_sharing_from_t2():
    m = Machine(cores=4, speed=1.0, background=0)
    # 4 programs from 0, one more at 8: the four end at 8 + 45 / 0.8, the last 8 s alone after
    assert window_end(m, 4, W - 8.0, 1, 8.0, W) == pytest.approx(8.0 + 45 / 0.8 + 8.0)
    assert window_end(m, 4, W - 8.0, 1, 8.0, W) == pytest.approx(finish(m, [0.0] * 4 + [8.0], W))
    assert window_end(m, 0, 0.0, 0, 8.0, W) == 0.0
    assert window_end(m, 2, 10.0, 0, 8.0, W) == pytest.approx(18.0)


def test_the_bounds_never_pass_the_optimum_and_solve_finds_it():
    rng = random.Random(5)
    proven_by_bound = 0
    for _ in range(40):
        team = [_random_machine(rng) for _ in range(rng.randint(2, 3))]
        rel = sorted(rng.choice((0.0, rng.uniform(0, 10))) for _ in range(rng.randint(1, 6)))
        best = _brute_force(team, rel)
        assert simple_bound(team, rel, W) <= best + 1e-6
        assert window_bound(team, rel, W, 0.0, best) <= best + 1e-6
        found = solve(team, rel, W, [0] * len(rel), time_limit=30.0)
        assert found.proven and found.best == pytest.approx(best)
        assert found.bound <= found.best + 1e-9 and found.gap == 0.0
        proven_by_bound += found.how == "bound"
    assert proven_by_bound > 0  # the bounds alone settle some


def test_the_window_bound_is_stronger_than_the_sweeps():
    sc = generate("idle", "staggered", 10, 0)  # 11 robots, 54 programs, staggered over 10 s
    team, rel = machines(sc), releases(sc)
    orc, placed = oracle_schedule(sc)
    lb = lower_bound(sc)
    wb = window_bound(team, rel, W, lb, orc)
    assert lb * 1.05 < wb <= orc


def test_improve_keeps_a_real_schedule_and_never_gets_worse():
    for index in (0, 7, 11):
        sc = generate("mixed", "staggered", index, 0)
        team, rel = machines(sc), releases(sc)
        orc, placed = oracle_schedule(sc)
        assert makespan_of(team, rel, W, placed) == pytest.approx(orc)
        got, better = improve(team, rel, W, placed)
        assert got <= orc + 1e-9
        assert makespan_of(team, rel, W, better) == pytest.approx(got)


@pytest.mark.slow  # a few seconds of annealing
def test_annealing_climbs_out_of_the_oracle_s_local_optimum():
    """mixed-staggered-1 (12 robots, 87 programs): the oracle's placement is a local optimum
    of ``improve``; annealing finds a schedule at least 7% shorter, a real one, and never
    below the bound (the clairvoyant optimum parks early programs on slow robots)."""
    sc = generate("mixed", "staggered", 1, 0)
    team, rel = machines(sc), releases(sc)
    orc, placed = oracle_schedule(sc)
    up, start = improve(team, rel, W, placed)
    best, assignment = anneal(team, rel, W, start, steps=20_000)
    assert best == pytest.approx(makespan_of(team, rel, W, assignment))
    assert best <= 0.93 * min(orc, up)
    assert best >= window_bound(team, rel, W, lower_bound(sc), best) - 1e-6
    assert anneal(team, rel, W, start, steps=20_000) == (best, assignment)  # same seed, same schedule
    tiny = [Machine(2, 1.0, 0)]
    assert anneal(tiny, [0.0, 1.0], W, [0, 0]) == (makespan_of(tiny, [0.0, 1.0], W, [0, 0]), [0, 0])


def test_solve_out_of_time_reports_the_interval():
    sc = generate("loaded", "staggered", 11, 0)  # 20 robots, 180 programs
    team, rel = machines(sc), releases(sc)
    orc, placed = oracle_schedule(sc)
    found = solve(team, rel, W, placed, time_limit=0.3)
    assert not found.proven and found.how in ("time", "nodes")
    assert lower_bound(sc) - 1e-6 <= found.bound < found.best <= orc + 1e-9
    assert found.gap == pytest.approx(found.best / found.bound - 1)


def test_solve_says_what_is_wrong_with_its_input():
    team = [Machine(4, 1.0, 0)] * 2
    with pytest.raises(ValueError, match="assignment"):
        solve(team, [0.0, 1.0], W, [0])
    with pytest.raises(ValueError, match="assignment"):
        solve(team, [0.0, 1.0], W, [0, 2])
    with pytest.raises(ValueError, match="work"):
        solve(team, [0.0], 0.0, [0])


def _brute_online(team, rel) -> float:
    """min over placements of the worst ratio over prefixes ending at distinct release times."""
    cuts = [k for k in range(1, len(rel) + 1) if k == len(rel) or rel[k] > rel[k - 1]]
    opt = {k: _brute_force(team, rel[:k]) for k in cuts}
    return min(max(makespan_of(team, rel[:k], W, a[:k]) / opt[k] for k in cuts)
               for a in itertools.product(range(len(team)), repeat=len(rel)))


def test_the_online_limit_is_what_brute_force_finds():
    rng = random.Random(5)
    for _ in range(25):
        team = [_random_machine(rng) for _ in range(rng.randint(2, 3))]
        rel = sorted(rng.choice((0.0, rng.uniform(0, 10))) for _ in range(rng.randint(1, 6)))
        found = online_limit(team, rel, W)
        assert found is not None and found.ratio == pytest.approx(_brute_online(team, rel))
        assert found.ratio >= 1.0 - 1e-9 and len(found.assignment) == len(rel)


def test_the_online_bound_never_claims_more_than_the_exhaustive_limit():
    """online_bound shows without a search what online_limit finds by one: never more."""
    rng = random.Random(7)
    shown = 0
    for _ in range(25):
        team = [_random_machine(rng) for _ in range(rng.randint(2, 4))]
        rel = sorted(rng.choice((0.0, rng.uniform(0, 10), rng.uniform(0, 1))) for _ in range(rng.randint(1, 7)))
        exact = online_limit(team, rel, W)
        assert exact is not None
        bound = online_bound(team, rel, W, steps=2_000, time_limit=10.0)
        assert 1.0 <= bound.ratio <= exact.ratio + 1e-3, (team, rel, bound, exact.ratio)
        shown += bound.ratio > 1.0
    assert shown > 0  # and it does show something on some of them


@pytest.mark.slow  # about 10 s: a fixed number of annealing steps per prefix, not a time limit
def test_no_online_placement_is_within_five_percent_of_mixed_staggered_29():
    """6 robots, 27 programs, too many for online_limit: the clairvoyant optimum (at most
    54.9 s) parks early programs on robots that a placement deciding at their release
    cannot use without being far above the optimum of what was released so far."""
    sc = generate("mixed", "staggered", 29, 0)
    orc, placed = oracle_schedule(sc)
    found = online_bound(machines(sc), releases(sc), W, placed, time_limit=600.0)
    assert found.ratio > 1.05 and found.optimum_at_most < orc
    assert found.unusable and found.prefix_optima[-1] == found.optimum_at_most


def test_no_online_placement_is_within_five_percent_of_mixed_staggered_0_and_its_prefixes():
    # the one proven sweep scenario where ramps is above 5% of the optimum (1.051): any
    # placement that does not know the releases to come is at least 1.051 above on one of
    # its prefixes, ramps and the omniscient oracle included
    sc = generate("mixed", "staggered", 0, 0)
    found = online_limit(machines(sc), releases(sc), W)
    assert found is not None and found.ratio == pytest.approx(1.0511, abs=1e-4)
    assert found.prefix_optima[-1] == pytest.approx(55.854, abs=1e-3)
    assert online_limit(machines(sc), releases(sc), W, max_nodes=5) is None  # too big for the search: unknown
    burst = generate("idle", "burst", 0, 0)  # a burst of identical robots: online is optimal
    assert online_limit(machines(burst), releases(burst), W).ratio == pytest.approx(1.0)
