"""The paper's experiments: the faithful policy shows the paper's flaws, ours fixes them.

These are deterministic (fixed seeds), so the figures below are behaviour of
the model, not timings; they hold on any machine.
"""

from __future__ import annotations

import pytest

from ramps.experiments.paper import configurations, run_config, run_experiment, PaperSetup


@pytest.fixture(scope="module")
def unloaded():
    return {p: run_experiment("unloaded", policy=p, runs=3) for p in ("ramps", "paper")}


@pytest.fixture(scope="module")
def loaded():
    return run_experiment("loaded", policy="ramps", runs=3)


def test_experiment_shapes():
    assert len(configurations("unloaded")) == 24
    assert len(configurations("loaded")) == 24
    with pytest.raises(ValueError, match="unknown experiment"):
        configurations("sideways")


@pytest.mark.slow
def test_paper_policy_models_stale_information(unloaded):
    s = unloaded["paper"].summary
    assert s.distributions == 72
    # not perfect: stale reports overwrite bookings, saturating CPU load hides queues
    assert s.optimal_or_near_share < 1.0
    assert s.non_optimal > 0
    assert 0.7 <= s.optimal_or_near_share <= 0.95
    assert s.lost == 0 and s.duplicated == 0


@pytest.mark.slow
def test_ramps_policy_is_optimal_on_unloaded_teams(unloaded):
    s = unloaded["ramps"].summary
    assert s.optimal_or_near_share == 1.0
    assert s.optimal_share >= 0.9
    for cfg in unloaded["ramps"].configs:
        assert cfg.median_makespan <= 1.05 * cfg.median_round_robin, (cfg.team_size, cfg.programs)


@pytest.mark.slow
def test_ramps_policy_on_loaded_teams(loaded):
    s = loaded.summary
    assert s.free_core_violations == 0
    assert s.worst_ratio_to_optimum <= 1.10
    for cfg in loaded.configs:
        if cfg.programs == 10 and cfg.loaded in (1, 2):
            assert cfg.median_round_robin >= 2.0 * cfg.median_makespan


def test_baselines_measured_in_the_same_run():
    cfg = run_config(5, 10, 0, policy="ramps", runs=1, seed=7, setup=PaperSetup())
    run = cfg.runs[0]
    assert run.round_robin_distribution == [2, 2, 2, 2, 2]
    # one Pi with 10 programs on 4 cores: 53 * 10 / 4 s plus a little overhead
    assert run.single_makespan == pytest.approx(132.5, rel=0.02)
    assert run.speedup == pytest.approx(run.single_makespan / run.makespan)


def test_same_seed_same_report():
    a = run_config(3, 15, 0, policy="paper", runs=2, seed=11, setup=PaperSetup())
    b = run_config(3, 15, 0, policy="paper", runs=2, seed=11, setup=PaperSetup())
    assert [r.distribution for r in a.runs] == [r.distribution for r in b.runs]
    assert [r.makespan for r in a.runs] == [r.makespan for r in b.runs]
