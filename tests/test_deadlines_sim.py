"""Deadlines in the simulator: ProgramSpec(deadline=...), misses counted,
and the generated family of deadline workloads with its CP-SAT bound."""

from __future__ import annotations

import msgspec
import pytest

from ramps.experiments.deadlines import VARIANTS, generate, jobs_of, miss_bound, run_family
from ramps.sim.engine import simulate
from ramps.sim.scenario import ProgramSpec, RobotSpec, Scenario, ScenarioError


def _two_robots(deadline: float, on_miss: str = "run") -> Scenario:
    return Scenario(robots=[RobotSpec(name="o", cores=1), RobotSpec(name="w", cores=1, speed=2.0)],
                    programs=[ProgramSpec(origin="o", work=10.0, deadline=deadline, on_miss=on_miss)])


def test_a_deadline_met_and_one_missed_are_counted() -> None:
    met = simulate(_two_robots(8.0), seed=1)
    assert (met.deadlines, met.deadline_misses) == (1, 0)  # about 5 s on w (10 s on o is late)
    [rec] = met.programs
    assert rec.host == "w" and rec.deadline == pytest.approx(rec.submitted_at + 8.0) and not rec.missed_deadline
    missed = simulate(_two_robots(2.0), seed=1)
    assert (missed.deadlines, missed.deadline_misses, missed.completed) == (1, 1, 1)  # runs anyway, late


def test_on_miss_fail_and_local_in_the_simulator() -> None:
    failed = simulate(_two_robots(2.0, "fail"), seed=1)
    assert (failed.completed, failed.failed, failed.deadline_misses) == (0, 1, 1)
    assert "cannot meet its deadline" in failed.programs[0].error
    local = simulate(_two_robots(2.0, "local"), seed=1)
    assert local.programs[0].host == "o" and local.deadline_misses == 1


def test_deadlines_not_told_are_still_counted() -> None:
    res = simulate(_two_robots(2.0, "fail"), seed=1, deadlines=False)
    assert (res.completed, res.deadline_misses) == (1, 1)  # placed as if it had none


def test_scenario_checks_deadline_and_on_miss() -> None:
    for bad, path in ((ProgramSpec(origin="o", deadline=0.0), "deadline"),
                      (ProgramSpec(origin="o", on_miss="later"), "on_miss")):
        sc = Scenario(robots=[RobotSpec(name="o")], programs=[bad])
        with pytest.raises(ScenarioError, match=path):
            sc.check()


def test_the_family_is_reproducible_and_has_several_origins() -> None:
    a, b = generate(3, seed=5), generate(3, seed=5)
    assert msgspec.json.encode(a) == msgspec.json.encode(b)
    for i in range(10):
        sc = generate(i)
        assert len({p.origin for p in sc.programs}) >= 2
        assert all(p.deadline is not None for p in sc.programs)


def test_the_bound_never_exceeds_what_any_variant_reached() -> None:
    report = run_family(4, seed=0)
    assert [r.scenario for r in report.rows] == [f"deadlines-{i}" for i in range(4)]
    for row in report.rows:
        assert set(row.misses) == {v[0] for v in VARIANTS}
        assert row.bound is not None and 0 <= row.bound <= min(row.misses.values())
    assert set(report.miss_ratio) == {v[0] for v in VARIANTS} | {"bound"}


def test_the_bound_sees_an_impossible_deadline() -> None:
    # one robot, one core: two 10 s programs both due 12 s after release cannot both make it
    sc = Scenario(robots=[RobotSpec(name="o", cores=1)],
                  programs=[ProgramSpec(origin="o", count=2, work=10.0, deadline=12.0)])
    assert len(jobs_of(sc)) == 2
    assert miss_bound(sc) == (1, True)
    assert simulate(sc, seed=1).deadline_misses >= 1


def test_the_exact_optimum_under_processor_sharing_and_the_bound() -> None:
    from ramps.experiments.deadlines_optimum import optimum

    # two 10 s programs due 12 s after release on one core: sharing it, both
    # end at 20 s; the bound (any schedule) leaves one miss
    sc = Scenario(robots=[RobotSpec(name="o", cores=1)],
                  programs=[ProgramSpec(origin="o", count=2, work=10.0, deadline=12.0)])
    assert optimum(sc).misses == 2 and miss_bound(sc)[0] == 1
    # a second robot takes one: none misses
    two = msgspec.structs.replace(sc, robots=[*sc.robots, RobotSpec(name="w", cores=1)])
    best = optimum(two)
    assert best.misses == 0 and sorted(best.hosts) == ["o", "w"]
    assert best.makespan == pytest.approx(10.0 + 0.016, abs=0.01)


def test_told_deadlines_miss_fewer_than_ignored_ones_on_the_family() -> None:
    from ramps.experiments.deadlines_optimum import small_scenarios

    told = ignored = 0
    for sc in small_scenarios(12):
        told += simulate(sc, policy="ramps", seed=1).deadline_misses
        ignored += simulate(sc, policy="ramps", seed=1, deadlines=False).deadline_misses
    assert told < ignored
