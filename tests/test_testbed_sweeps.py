"""The testbed sweeps' simulator side and configuration checks
(ramps.lab.sweeps): pure, milliseconds; the testbed side needs root and
minutes, and is run by ``ramps testbed experiment sweep``."""

from __future__ import annotations

import msgspec
import pytest

from ramps.lab.sweeps import (
    DEFAULT_CONFIGS,
    FULL_CONFIGS,
    SweepCase,
    TestbedSweepReport,
    format_report,
    run_testbed_sweep,
    shared_makespan,
    sim_scenario,
    simulate_config,
)


def test_the_simulated_team_is_the_testbed_configuration():
    sc = sim_scenario(5, 4, 2, 3, cores=4, speed=0.05, work=0.3)
    team = sc.team()
    assert [r.name for r in team] == ["r1", "r2", "r3", "r4", "r5"]
    assert [r.background for r in team] == [0, 0, 0, 8, 8]  # the last robots are the loaded ones, as in Table 4
    assert {r.worker_nice for r in team} == {10}  # the node's workers run at nice 10 against the busy load
    assert {r.speed for r in team} == {0.05}
    assert [p.origin for p in sc.programs] == ["r1", "r2", "r3"]
    assert {(p.count, p.work, p.spacing) for p in sc.programs} == {(4, 0.3, 0.05)}
    assert sc.publisher.period == 1.0  # a node reports every second, not the paper's 2 s


def test_two_origins_on_three_idle_robots_even_out_in_the_simulator():
    # issue 10's example: r1 and r2 each submit 6; 4-4-4 is the optimum
    makespan, dists = simulate_config(3, 6, 0, 2, cores=4, speed=0.05, work=0.3, seeds=2)
    assert dists == [[4, 4, 4], [4, 4, 4]]
    assert makespan == pytest.approx(0.3 / 0.05, rel=0.1)


def test_distributions_of_programs_on_cores_of_their_own_are_as_good():
    """15 programs from 3 origins on 5 idle robots of 4 cores: 3-3-3-3-3 and
    3-3-3-4-2 both run each on a core of its own, 5-3-3-2-2 shares one
    robot's cores; a robot with 8 busy processes gives nice-10 programs a
    sliver of its cores."""
    kw = dict(cores=4, speed=0.05, work=0.3)
    idle = [0] * 5
    assert shared_makespan([3, 3, 3, 3, 3], idle, **kw) == shared_makespan([3, 3, 3, 4, 2], idle, **kw) == pytest.approx(6.0)
    assert shared_makespan([5, 3, 3, 2, 2], idle, **kw) == pytest.approx(6.0 * 5 / 4)
    loaded = shared_makespan([4, 4, 4, 3, 0], [0, 0, 0, 0, 8], **kw)
    assert loaded == pytest.approx(6.0) and shared_makespan([4, 4, 4, 2, 1], [0, 0, 0, 0, 8], **kw) > 5 * loaded
    assert shared_makespan([], [], **kw) == 0.0


def test_a_case_puts_the_testbed_beside_the_simulator():
    """What a burst on the testbed becomes in the report: the ratios, and the
    distribution as good as the simulator's though not one of its seeds'."""
    from ramps.lab.sweeps import _Burst, _case

    b = _Burst(makespan=13.2, distribution=[3, 3, 3, 3, 3], completed=15, failed=0, spent=15 * 0.3 * 2.2,
               obtained=0.95)
    c = _case(("multi-origin", 5, 5, 0, 3), b, 12.0, [[3, 3, 3, 4, 2], [3, 3, 3, 2, 4]], {"r1": 0.05, "r2": 0.05},
              busy={}, names=["r1", "r2", "r3", "r4", "r5"], cores=4, speed=0.05, work=0.3, calibration=2.0)
    assert (c.ratio, c.unit_cpu, c.corrected_ratio, c.starved_ratio) == (1.1, 2.2, 1.0, 0.95)
    assert not c.same and c.as_good and c.model_testbed == c.model_sim == 6.0
    worse = _case(("loaded", 5, 15, 1, 1), msgspec.structs.replace(b, distribution=[4, 4, 4, 2, 1]), 12.0,
                  [[4, 4, 4, 3, 0]], {}, busy={"r5": 8}, names=["r1", "r2", "r3", "r4", "r5"], cores=4,
                  speed=0.05, work=0.3, calibration=2.0)
    assert not worse.same and not worse.as_good and worse.model_testbed > 5 * worse.model_sim


def test_loaded_robots_get_nothing_while_idle_cores_remain():
    _, dists = simulate_config(5, 15, 2, 1, cores=4, speed=0.05, work=0.3, seeds=2)
    for d in dists:
        assert sum(d) == 15 and d[3:] == [0, 0]


@pytest.mark.parametrize("bad", [("unloaded", 3, 5, 0, 4), ("loaded", 3, 5, 3, 1), ("nonsense", 3, 5, 0, 1),
                                 ("unloaded", 3, 0, 0, 1)])
def test_a_bad_configuration_is_refused_before_anything_starts(bad):
    with pytest.raises(ValueError, match="bad configuration"):
        run_testbed_sweep([bad])


def test_every_listed_configuration_is_valid_and_the_default_covers_each_experiment():
    assert {c[0] for c in DEFAULT_CONFIGS} == {"unloaded", "loaded", "multi-origin"}
    for exp, n, k, loaded, origins in FULL_CONFIGS:
        assert 1 <= origins <= n and 0 <= loaded < n and k >= 1


def test_the_report_prints_both_worlds_side_by_side():
    case = SweepCase(experiment="multi-origin", robots=3, programs=6, loaded=0, origins=2, makespan=11.0,
                     distribution=[4, 5, 3], sim_makespan=10.0, sim_distributions=[[4, 4, 4]], ratio=1.1,
                     unit_cpu=1.6, calibration=1.5, corrected_ratio=1.03, completed=12, failed=0, host_load=3.0)
    rep = TestbedSweepReport(cores=4, quota=0.2, speed=0.033, work=0.3, seeds=1, cases=[case],
                             mean_abs_ratio_error=0.1, mean_abs_corrected_error=0.03)
    text = format_report(rep)
    assert "2 x 6" in text and "4-5-3 / 4-4-4" in text and "1.10" in text and "1.03" in text


def test_a_process_keeps_the_kind_it_was_first_given_while_its_cpu_is_updated():
    from ramps.lab.fidelity import merge_cpu

    seen = {10: ("worker", 1.0), 11: ("node", 0.5)}
    # an exiting worker (a zombie) has an empty command line and reads as "other"
    merge_cpu(seen, {10: ("other", 1.5), 11: ("node", 0.6), 12: ("fork_server", 0.1)})
    assert seen == {10: ("worker", 1.5), 11: ("node", 0.6), 12: ("fork_server", 0.1)}
