"""``ramps bench team-size --cpu-quota``'s simulator side: the same team and
burst in the simulator, and the real makespan over each simulated one.

Runs the real simulator on small teams whose answers are known by hand:
one-core robots, identical programs submitted at once, processor sharing.
"""

from __future__ import annotations

import pytest

from ramps.bench.teamsize_sim import compare, scenario


def test_the_scenario_is_the_bench_team():
    sc = scenario(4, {"r1": 5, "r2": 3, "r3": 0}, units=2.0, speed=0.5, node_cpu=0.25)
    assert [(r.name, r.count, r.cores, r.speed, r.node_cpu) for r in sc.robots] == [("r{i}", 4, 1, 0.5, 0.25)]
    assert {(p.origin, p.count, p.work, p.at) for p in sc.programs} == {("r1", 5, 2.0, 0.0), ("r2", 3, 2.0, 0.0)}


def test_two_programs_a_robot_take_twice_a_program_alone_and_ratios_are_real_over_simulated():
    # 8 programs of 1 unit on 4 one-core robots of speed 1: two on each, sharing, end at ~2 s
    burst = {"makespan_s": 5.0, "median_turnaround_s": 4.0}
    out = compare(burst, n=4, per_origin={"r1": 4, "r2": 4}, units=1.0, speed=1.0, node_cpu=0.5)
    ideal = out["ideal"]
    assert ideal["robots_by_programs"] == {"2": 4}
    assert ideal["makespan_s"] == pytest.approx(2.0, abs=0.1)
    # a node taking half of each core: the programs get the other half
    assert out["with_node"]["makespan_s"] == pytest.approx(2 * ideal["makespan_s"], rel=0.1)
    # at the speed the real programs got (4 s where the simulator's took ~2 s): the real run's time
    assert out["host_factor"] == pytest.approx(4.0 / ideal["median_turnaround_s"], rel=1e-3)
    assert out["corrected"]["makespan_s"] == pytest.approx(4.0, rel=0.05)
    assert out["ratio_ideal"] == pytest.approx(5.0 / ideal["makespan_s"], rel=1e-3)
    assert out["ratio_corrected"] == pytest.approx(5.0 / out["corrected"]["makespan_s"], rel=1e-3)


def test_no_ratio_without_a_finished_burst():
    out = compare({"makespan_s": None, "median_turnaround_s": None}, n=2, per_origin={"r1": 2}, units=1.0,
                  speed=1.0, node_cpu=0.0)
    assert "ratio_ideal" not in out and out["ideal"]["robots_by_programs"] == {"1": 2}
