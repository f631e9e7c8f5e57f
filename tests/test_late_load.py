"""Relocation in the simulator: load that changes after placement, programs
that checkpoint, and the fault campaign with both (milliseconds each)."""

from __future__ import annotations

import pytest

from ramps.experiments.campaign import random_scenario, run_one
from ramps.experiments.late_load import finish_time, hindsight_optimum, run_relocation
from ramps.sim.engine import simulate
from ramps.sim.scenario import FaultSpec, ProgramSpec, RobotSpec, Scenario, ScenarioError


def test_relocation_ends_near_the_hindsight_optimum_and_off_it_does_not():
    rep = run_relocation(seeds=1)
    by = {r.variant: r for r in rep.runs}
    assert rep.hindsight_optimum == pytest.approx(60.0)
    assert by["relocation + checkpoints"].ratio <= 1.10
    assert by["relocation"].makespan < 0.6 * by["relocation off"].makespan
    assert by["relocation off"].moves == 0 and by["relocation off"].ratio > 2.0
    assert by["relocation + checkpoints"].resumed > 0
    assert all(r.lost == 0 and r.duplicated == 0 for r in rep.runs)


def test_the_hindsight_optimum_avoids_the_robot_that_will_get_busy():
    assert finish_time(4, 60.0, 4, 1.0, 8, 10.0) == pytest.approx(10.0 + 50.0 * 3.0)
    assert hindsight_optimum(3, 4, 8, 60.0, 0, 0, 10.0) == (60.0, [0, 4, 4])
    t, split = hindsight_optimum(3, 4, 8, 60.0, 0, 8, 10.0)
    assert t == pytest.approx(60.0) and split[0] == 0


def test_a_load_change_slows_the_robots_programs_down():
    def sc(faults):
        return Scenario(robots=[RobotSpec(name="r1", cores=2)],
                        programs=[ProgramSpec(origin="r1", count=2, work=20.0)], faults=faults)
    assert simulate(sc([])).makespan == pytest.approx(20.0, abs=0.5)
    # two busy processes from t=10 halve the programs' speed for the last 10 units
    assert simulate(sc([FaultSpec(at=10.0, robot="r1", kind="load", background=2)])).makespan == \
        pytest.approx(30.0, abs=0.5)


def test_a_load_change_needs_its_busy_processes():
    base = dict(robots=[RobotSpec(name="r1")], programs=[ProgramSpec(origin="r1")])
    with pytest.raises(ScenarioError, match=r"faults\[0\].background"):
        Scenario(**base, faults=[FaultSpec(at=1.0, robot="r1", kind="load")]).check()
    with pytest.raises(ScenarioError, match="only a 'load'"):
        Scenario(**base, faults=[FaultSpec(at=1.0, robot="r1", kind="crash", background=3)]).check()


def test_the_campaign_with_load_changes_keeps_exactly_once():
    import random
    plain = random_scenario(random.Random(7), 7, "ramps")
    assert plain == random_scenario(random.Random(7), 7, "ramps", False)
    loaded = random_scenario(random.Random(7), 7, "ramps", True)
    assert any(f.kind == "load" for f in loaded.faults)
    moves = 0
    for seed in range(6):
        run = run_one(seed, load_changes=True)
        assert run.ok, run
        moves += run.moves
    assert moves > 0


def test_relocation_against_none_on_campaign_scenarios():
    from ramps.experiments.late_load import compare_on_campaign
    rep = compare_on_campaign(3)
    assert rep.runs == 3 and len(rep.ratios) == 3 and rep.lost == 0 and rep.duplicated == 0
    assert rep.ratios == sorted(rep.ratios) and all(r > 0 for r in rep.ratios)
