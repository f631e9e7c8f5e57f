"""The simulator: processor sharing, stale load reports, faults and recovery."""

from __future__ import annotations

import pytest

from ramps.sim.cpu import CPU
from ramps.sim.engine import simulate
from ramps.sim.scenario import FaultSpec, NetworkSpec, ProgramSpec, RobotSpec, Scenario


def test_processor_sharing_rates():
    cpu = CPU(cores=2, speed=1.0, background=0, now=0.0)
    for i in range(4):
        cpu.add((f"p{i}", 1), 10.0, 0.0)
    t, _ = cpu.next_completion()
    assert t == pytest.approx(20.0)  # 4 tasks on 2 cores: half speed each
    cpu.remove(("p0", 1), 10.0)  # at t=10 each has 5 left; now 3 tasks share 2 cores
    t, _ = cpu.next_completion()
    assert t == pytest.approx(10.0 + 5.0 / (2 / 3))


def test_background_load_slows_programs_and_shows_in_averages():
    cpu = CPU(cores=4, speed=1.0, background=8, now=0.0)
    cpu.add(("p", 1), 9.0, 0.0)
    t, _ = cpu.next_completion()
    assert t == pytest.approx(9.0 / (4 / 9))
    busy, runnable, ramps = cpu.averages(2.0, 1.0)
    assert (busy, runnable, ramps) == pytest.approx((4.0, 9.0, 1.0))


def test_niced_programs_get_what_the_background_leaves():
    """CFS shares: a nice-10 program next to a nice-0 busy loop on one core
    gets 110/1134 of it; next to 3 busy loops on 4 cores, the fourth core."""
    from ramps.core.cost import nice_weight

    w = nice_weight(10)
    cpu = CPU(cores=1, speed=1.0, background=1, now=0.0, weight=w)
    cpu.add(("p", 1), 1.0, 0.0)
    t, _ = cpu.next_completion()
    assert t == pytest.approx(1134 / 110)
    assert cpu.averages(2.0, 1.0)[0] == pytest.approx(1.0)  # the core stays fully busy
    cpu = CPU(cores=4, speed=1.0, background=3, now=0.0, weight=w)
    for i in range(2):
        cpu.add((f"p{i}", 1), 5.0, 0.0)
    t, _ = cpu.next_completion()
    assert t == pytest.approx(10.0)  # two programs share the one free core
    assert cpu.averages(2.0, 1.0)[:2] == pytest.approx((4.0, 5.0))


def test_the_simulated_team_avoids_a_robot_whose_own_software_is_busy():
    """r2 has 4 cores and 3 busy processes of its own; r3 is idle but slower.
    At equal weights (the paper's world) a second program on r2 gets 0.8 of
    a core (25 s) and beats r3 (28.6 s). With workers at nice 10 it would
    get half of the one free core (40 s), so it goes to r3 instead and the
    makespan stays r3's."""
    def run(nice: int):
        robots = [RobotSpec(name="r1", cores=1), RobotSpec(name="r2", cores=4, background=3, worker_nice=nice),
                  RobotSpec(name="r3", cores=4, speed=0.7)]
        return simulate(Scenario(name="t", robots=robots, seed=1,
                                 programs=[ProgramSpec(origin="r1", count=4, work=20.0)]))

    assert run(0).distribution == {"r1": 1, "r2": 2, "r3": 1}
    niced = run(10)
    assert niced.distribution == {"r1": 1, "r2": 1, "r3": 2}
    assert niced.makespan == pytest.approx(20.0 / 0.7, rel=0.01)


def test_averages_cover_only_the_window():
    cpu = CPU(cores=4, speed=1.0, background=0, now=0.0)
    cpu.add(("p", 1), 100.0, 9.5)  # started half-way through the window [9, 10]
    busy, runnable, ramps = cpu.averages(10.0, 1.0)
    assert busy == pytest.approx(0.5) and ramps == pytest.approx(0.5)


def team(n=3, cores=2, **kw):
    return [RobotSpec(name=f"r{i}", cores=cores, **kw) for i in range(1, n + 1)]


def scenario(**kw):
    base = dict(name="t", robots=team(), programs=[ProgramSpec(origin="r1", count=6, work=20.0)], seed=1)
    base.update(kw)
    return Scenario(**base)


def test_no_faults_everything_completes_and_spreads():
    res = simulate(scenario())
    assert res.completed == 6 and res.lost == 0 and res.duplicated == 0
    assert res.distribution == {"r1": 2, "r2": 2, "r3": 2}
    assert res.makespan == pytest.approx(20.0, rel=0.02)


@pytest.mark.parametrize("kind", ["crash", "network", "freeze"])
def test_a_failed_host_is_written_off_and_its_programs_restarted(kind):
    res = simulate(scenario(faults=[FaultSpec(at=5.0, robot="r3", kind=kind)]), trace=True)
    assert res.completed == 6 and res.lost == 0 and res.duplicated == 0
    assert res.distribution["r3"] == 0
    blacklisted = [e for e in res.trace if e.what == "blacklisted"]
    assert blacklisted and all(e.other == "r3" for e in blacklisted)
    # restarted from scratch (weak mobility), after detection and back-off
    assert res.makespan > 25.0


@pytest.mark.parametrize("kind", ["crash", "network", "freeze"])
def test_detection_without_liveliness_uses_heartbeats(kind):
    net = NetworkSpec(liveliness=False)
    res = simulate(scenario(network=net, faults=[FaultSpec(at=5.0, robot="r2", kind=kind)]), trace=True)
    assert res.completed == 6 and res.duplicated == 0
    failed = [e for e in res.trace if e.what == "failed"]
    assert failed and {e.detail for e in failed} <= {"heartbeat_timeout", "connect_timeout"}


def test_a_frozen_host_that_thaws_has_its_stale_results_discarded():
    res = simulate(scenario(faults=[FaultSpec(at=5.0, robot="r3", kind="freeze"),
                                    FaultSpec(at=8.0, robot="r3", kind="recover")]), trace=True)
    assert res.completed == 6 and res.duplicated == 0 and res.lost == 0
    assert res.distribution["r3"] == 0 or any(e.what == "unblacklisted" for e in res.trace)


def test_a_crashed_robot_that_recovers_is_used_again_once_it_publishes():
    sc = scenario(programs=[ProgramSpec(origin="r1", count=6, work=20.0),
                            ProgramSpec(origin="r1", count=6, work=20.0, at=30.0)],
                  faults=[FaultSpec(at=2.0, robot="r3", kind="crash"), FaultSpec(at=10.0, robot="r3", kind="recover")])
    res = simulate(sc, trace=True)
    assert res.completed == 12 and res.lost == 0 and res.duplicated == 0
    assert any(e.what == "unblacklisted" and e.other == "r3" for e in res.trace)
    assert res.distribution["r3"] >= 1  # the second wave used it again


def test_an_origin_cut_off_runs_its_programs_itself():
    sc = scenario(faults=[FaultSpec(at=3.0, robot="r1", kind="network")])
    res = simulate(sc, trace=True)
    assert res.completed == 6 and res.duplicated == 0 and res.lost == 0
    assert res.distribution == {"r1": 6, "r2": 0, "r3": 0}


def test_lossy_network_still_delivers_exactly_once():
    res = simulate(scenario(network=NetworkSpec(loss=0.2), programs=[ProgramSpec(origin="r1", count=12, work=5.0)]))
    assert res.completed == 12 and res.duplicated == 0 and res.lost == 0


def test_crashed_origin_programs_are_not_counted_lost():
    sc = scenario(faults=[FaultSpec(at=1.0, robot="r1", kind="crash")])
    res = simulate(sc)
    assert res.lost == 0 and res.completed == 0
    assert all(p.error == "origin crashed" for p in res.programs)


def test_same_seed_same_trace_different_seed_differs():
    sc = scenario(policy="random", programs=[ProgramSpec(origin="r1", count=12, work=5.0, spacing=0.3)])
    a, b = simulate(sc, trace=True), simulate(sc, trace=True)
    assert a.trace == b.trace and a.distribution == b.distribution
    c = simulate(sc, seed=99, trace=True)
    assert c.trace != a.trace


def test_snapshots_show_where_programs_run():
    res = simulate(scenario(), snapshots=[10.0])
    assert res.snapshots["10"] == {"r1": 2, "r2": 2, "r3": 2}


def test_a_worker_niceness_outside_linuxs_range_is_refused():
    from ramps.sim.scenario import ScenarioError

    sc = Scenario(name="t", robots=[RobotSpec(name="r1", worker_nice=25)],
                  programs=[ProgramSpec(origin="r1")], seed=1)
    with pytest.raises(ScenarioError, match="worker_nice"):
        sc.check()
