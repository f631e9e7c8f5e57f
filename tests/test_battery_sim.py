"""Batteries in the simulator (``ramps.sim.battery``): a robot that drops
below its reserve mid-run hands back what it hosts within one report
period, and every program still finishes once; batteries drain with busy
cores; the energy a run used."""

from __future__ import annotations

import msgspec
import pytest

from ramps.core.config import RampsConfig
from ramps.sim.engine import simulate
from ramps.sim.scenario import FaultSpec, ProgramSpec, PublisherSpec, RobotSpec, Scenario, ScenarioError


def _team(**r2) -> list[RobotSpec]:
    return [RobotSpec(name="r1", cores=1, speed=1.0), RobotSpec(name="r2", cores=4, speed=2.0, **r2),
            RobotSpec(name="r3", cores=4, speed=1.0), RobotSpec(name="r4", cores=2, speed=1.0)]


def _scenario(faults=(), checkpoint_every: float = 0.0, **r2) -> Scenario:
    return Scenario(name="battery", robots=_team(**r2), faults=list(faults),
                    programs=[ProgramSpec(origin="r1", count=8, work=40.0, spacing=0.05,
                                          checkpoint_every=checkpoint_every, checkpoint_size=100)])


@pytest.mark.parametrize("checkpoint_every", [0.0, 2.0])
def test_a_robot_that_drops_below_its_reserve_mid_run_sheds_and_every_program_finishes(checkpoint_every):
    sc = _scenario([FaultSpec(at=10.0, robot="r2", kind="battery", charge=0.1)], checkpoint_every, battery=0.9)
    before = simulate(_scenario(checkpoint_every=checkpoint_every, battery=0.9), trace=True)
    assert any(p.host == "r2" for p in before.programs), "r2, the fastest, hosts programs when charged"
    res = simulate(sc, trace=True)
    assert (res.completed, res.lost, res.duplicated, res.failed) == (8, 0, 0, 0)
    assert all(p.host != "r2" for p in res.programs)
    [low] = [e for e in res.trace if e.what == "battery_low"]
    fault_at = sc.warmup + 10.0
    assert fault_at <= low.t <= fault_at + sc.publisher.period  # within one report period
    handed = [e for e in res.trace if e.what == "failed" and e.other == "r2"]
    assert handed and all("below its battery reserve" in e.detail for e in handed)
    assert not [e for e in res.trace if e.what == "blacklisted"]  # handed back, not written off
    if checkpoint_every:  # those it ran resume from their checkpoints elsewhere
        assert sum(1 for p in res.programs if p.resumed_from) == len(handed)
    assert res.charge == {"r2": pytest.approx(0.1, abs=0.01)}


def test_without_a_reserve_the_same_drop_changes_nothing() -> None:
    sc = _scenario([FaultSpec(at=10.0, robot="r2", kind="battery", charge=0.1)], battery=0.9)
    off = msgspec.structs.replace(sc, config=RampsConfig(battery_reserve=0.0))
    plain = simulate(_scenario(battery=0.9))
    res = simulate(off)
    assert res.makespan == plain.makespan and res.distribution == plain.distribution


def test_a_battery_drains_with_busy_cores_until_the_robot_sheds() -> None:
    # 0.01 a busy core-second: r2's charge of 0.5 falls below 0.2 after 30 busy core-seconds
    res = simulate(_scenario(battery=0.5, drain=0.01), trace=True)
    assert res.completed == 8 and not res.lost and not res.duplicated
    assert [e for e in res.trace if e.what == "battery_low" and e.robot == "r2"]
    assert res.charge["r2"] < 0.2


def test_energy_is_busy_core_seconds_times_power() -> None:
    sc = Scenario(name="energy", robots=[RobotSpec(name="r1", cores=2, speed=2.0, power=10.0),
                                         RobotSpec(name="r2", cores=1, speed=1.0)],
                  programs=[ProgramSpec(origin="r1", count=2, work=20.0, spacing=0.0)],
                  publisher=PublisherSpec(period=1.0, window=1.0))
    res = simulate(sc, policy="local_only")
    # two programs of 20 units on r1's two cores at speed 2: 20 core-seconds at 10 W
    assert res.energy == {"r1": pytest.approx(200.0, rel=1e-6), "r2": 0.0}
    assert res.charge == {}
    res = simulate(msgspec.structs.replace(sc, robots=[msgspec.structs.replace(r, power=None) for r in sc.robots]),
                   policy="local_only")
    assert res.energy["r1"] == pytest.approx(20.0, rel=1e-6)  # no power given: core-seconds


@pytest.mark.parametrize("robot, fault, path", [
    (dict(battery=1.5), None, "$.robots[1].battery"),
    (dict(drain=-0.1), None, "$.robots[1].drain"),
    (dict(power=0.0), None, "$.robots[1].power"),
    ({}, FaultSpec(at=1.0, robot="r2", kind="battery"), "$.faults[0].charge"),
    ({}, FaultSpec(at=1.0, robot="r2", kind="battery", charge=2.0), "$.faults[0].charge"),
    ({}, FaultSpec(at=1.0, robot="r2", kind="crash", charge=0.5), "$.faults[0].charge"),
])
def test_scenarios_with_impossible_batteries_are_refused(robot, fault, path) -> None:
    sc = _scenario([fault] if fault else [], **robot)
    with pytest.raises(ScenarioError) as err:
        sc.check()
    assert err.value.path == path
