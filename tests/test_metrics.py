"""Distribution quality: the paper's classification and the exact optimum."""

from __future__ import annotations

import itertools

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ramps.experiments.metrics import (
    Machine,
    classify,
    classify_counts,
    finish_time,
    free_core_violation,
    model_makespan,
    optimal_allocation,
)


@pytest.mark.parametrize(
    "counts, expected",
    [
        ([1, 1, 1, 1, 1], "optimal"),
        ([3, 4, 4, 4], "optimal"),
        ([2, 3, 3, 3, 4], "near_optimal"),  # one move from 4 to 2
        ([7, 8], "optimal"),
        ([9, 6], "near_optimal"),
        ([1, 2, 3, 2, 2], "near_optimal"),  # the paper's own example, 10 RAMPs on 5 robots
        ([9, 10, 6], "non_optimal"),  # the paper's biggest discrepancy
        ([8, 12], "non_optimal"),
    ],
)
def test_paper_classification(counts, expected):
    assert classify_counts(counts) == expected


def test_finish_time_processor_sharing():
    pi = Machine(4, 1.0)
    assert finish_time(pi, 4, 53) == pytest.approx(53)
    assert finish_time(pi, 6, 53) == pytest.approx(53 * 6 / 4)
    stressed = Machine(4, 1.0, background=8)
    assert finish_time(stressed, 1, 53) == pytest.approx(53 * 9 / 4)


def brute_force(n, team, work):
    best = None
    for counts in itertools.product(range(n + 1), repeat=len(team)):
        if sum(counts) == n:
            t = model_makespan(counts, team, work)
            best = t if best is None else min(best, t)
    return best


@settings(max_examples=60, deadline=None)
@given(
    team=st.lists(st.builds(Machine, st.integers(1, 4), st.sampled_from([0.5, 1.0, 2.0]), st.integers(0, 8)),
                  min_size=1, max_size=4),
    n=st.integers(1, 9),
)
def test_greedy_optimum_matches_brute_force(team, n):
    counts, t = optimal_allocation(n, team, 10.0)
    assert sum(counts) == n
    assert t == pytest.approx(model_makespan(counts, team, 10.0))
    assert t == pytest.approx(brute_force(n, team, 10.0))


def test_model_classification_for_loaded_teams():
    team = [Machine(4, 1.0)] * 3 + [Machine(4, 1.0, 8)] * 2
    assert classify([4, 3, 3, 0, 0], team, 53) == "optimal"
    assert classify([5, 3, 2, 0, 0], team, 53) == "near_optimal"  # one move: 5 -> 4
    assert classify([5, 5, 0, 0, 0], team, 53) == "non_optimal"  # needs two moves
    assert classify([2, 2, 2, 2, 2], team, 53) == "non_optimal"


def test_free_core_violation():
    team = [Machine(4, 1.0), Machine(4, 1.0, 8)]
    assert free_core_violation([3, 1], team)
    assert not free_core_violation([4, 1], team)
    assert not free_core_violation([3, 0], team)
