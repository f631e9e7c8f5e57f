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


def test_a_busy_origin_node_slows_its_own_robot_alone():
    """Each node's share during the burst, robot by robot: the median one is already in the
    programs' speed; a busier one (an origin's, a fifth of its core against a tenth) makes
    its robot's two programs end later, the makespan with them."""
    burst = {"makespan_s": 5.0, "median_turnaround_s": 4.0}
    nodes = {"r1": 0.2, "r2": 0.1, "r3": 0.1, "r4": 0.1}
    out = compare(burst, n=4, per_origin={"r1": 4, "r2": 4}, units=1.0, speed=1.0, node_cpu=0.1,
                  burst_node_cpu=nodes)
    assert out["burst_node_cpu"] == {"median": 0.1, "max": 0.2}
    # the median robot's programs as fast as in ``corrected``; r1's at 0.8 of the core over 0.9
    assert out["busy_node"]["makespan_s"] == pytest.approx(out["corrected"]["makespan_s"] * 0.9 / 0.8, rel=0.05)
    assert out["ratio_busy_node"] == pytest.approx(5.0 / out["busy_node"]["makespan_s"], rel=1e-3)
    even = compare(burst, n=4, per_origin={"r1": 4, "r2": 4}, units=1.0, speed=1.0, node_cpu=0.1,
                   burst_node_cpu=dict.fromkeys(nodes, 0.1))
    assert even["busy_node"]["makespan_s"] == pytest.approx(even["corrected"]["makespan_s"], rel=0.02)


def test_a_node_busier_than_half_its_core_counts_as_half():
    """An origin's node on a fiftieth of a host core took 0.71 of its core during a burst;
    the simulator's node takes at most half (``NODE_CPU_MAX``): the comparison still runs."""
    out = compare({"makespan_s": 5.0, "median_turnaround_s": 4.0}, n=2, per_origin={"r1": 2}, units=1.0,
                  speed=1.0, node_cpu=0.7, burst_node_cpu={"r1": 0.71, "r2": 0.1})
    assert out["burst_node_cpu"]["max"] == 0.71 and out["busy_node"]["makespan_s"] > 0
    assert out["with_node"]["makespan_s"] > out["ideal"]["makespan_s"]
