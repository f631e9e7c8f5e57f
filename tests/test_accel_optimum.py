"""The accelerator family's exact reference (``ramps.experiments.accel_optimum``)
on instances small enough to check by hand, and its generator."""

from __future__ import annotations

from typing import Any

import pytest

from ramps.core.cost import NetworkEstimate, comm_time
from ramps.experiments.accel_optimum import greedy, makespan_of, optimum, shared_batch_end
from ramps.experiments.accelerators import FAMILIES, family_of, generate
from ramps.sim.scenario import FaultSpec, ProgramSpec, RobotSpec, Scenario

COMM = comm_time(1000, 1000, NetworkEstimate())  # the default network, default sizes


def gpu_pair(count: int = 4, **program: Any) -> Scenario:
    """``a``: one core of speed 1; ``g``: the same and one cuda slot of speed 20."""
    spec: dict[str, Any] = dict(program="detect", origin="a", count=count, work=10.0, accelerator="cuda", accelerator_work=20.0)
    spec.update(program)
    return Scenario(robots=[RobotSpec(name="a", cores=1), RobotSpec(name="g", cores=1, accelerators=["cuda:1:20"])],
                    programs=[ProgramSpec(**spec)]).check()


def test_processor_sharing_of_a_batch_is_not_the_packing_bound() -> None:
    assert shared_batch_end([1.0, 1.0, 10.0], 2) == 10.5  # the packing bound says max(10, 12 / 2) = 10
    assert shared_batch_end([3.0, 3.0, 3.0], 2) == 4.5  # equal programs: the bound, 9 / 2
    assert shared_batch_end([2.0, 5.0], 4) == 5.0
    assert shared_batch_end([], 2) == 0.0


def test_the_optimum_of_one_robot_is_its_processor_sharing_makespan() -> None:
    sc = Scenario(robots=[RobotSpec(name="a", cores=2)],
                  programs=[ProgramSpec(origin="a", work=1.0, count=2), ProgramSpec(origin="a", work=10.0)])
    opt = optimum(sc)
    assert opt.proven and opt.makespan == pytest.approx(10.5) and opt.bound <= opt.makespan


def test_programs_go_to_the_slot_where_it_is_faster_and_pay_the_link() -> None:
    opt = optimum(gpu_pair())  # 1 s each on the slot, 10 s on a core: all four on the slot
    assert opt.proven and opt.hosts == ["g:cuda"] * 4
    assert opt.makespan == pytest.approx(4.0 + COMM)


def test_a_slow_slot_leaves_the_work_to_the_cores() -> None:
    # 20 units on a speed-20 slot is 1 s; 400 units is 20 s there, and 10 s on a core
    opt = optimum(gpu_pair(count=2, accelerator_work=400.0))
    assert opt.hosts == ["a", "a"] and opt.makespan == pytest.approx(20.0)  # g would run one on its slot: 20 s
    relaxed = optimum(gpu_pair(count=2, accelerator_work=400.0), choose_device=True)
    assert relaxed.makespan == pytest.approx(10.0 + COMM) and sorted(relaxed.hosts) == ["a", "g"]


def test_a_program_that_needs_the_slot_never_runs_on_a_core() -> None:
    opt = optimum(gpu_pair(count=3, accelerator_work=400.0, cpu_fallback=False))
    assert opt.hosts == ["g:cuda"] * 3 and opt.makespan == pytest.approx(60.0 + COMM)


def test_a_robot_that_fails_takes_only_what_it_ends_before() -> None:
    sc = gpu_pair()
    crash = Scenario(robots=sc.robots, programs=sc.programs, faults=[FaultSpec(at=2.0, robot="g", kind="crash")])
    opt = optimum(crash)
    # two on the slot would end at 2 s plus the link, after the crash: one there, three on a's core
    assert sorted(opt.hosts) == ["a", "a", "a", "g:cuda"]
    assert opt.makespan == pytest.approx(30.0)
    assert makespan_of(crash, opt.hosts) == opt.makespan


def test_the_rule_with_a_perfect_view_is_never_better_than_the_optimum() -> None:
    for i in range(0, 15, 5):  # the mixed kind
        sc = generate(i)
        opt = optimum(sc)
        assert greedy(sc)[0] >= opt.bound - 1e-9


def test_the_rule_by_declared_work_chooses_by_it_and_is_measured_by_the_true_work() -> None:
    # one program: 1 s on g's slot (true), declared 16x that: 16 s, so by the
    # declaration a's core (10 s) is sooner, and the true makespan is a's 10 s
    sc = gpu_pair(count=1, accelerator_estimate=320.0)
    assert greedy(sc) == (pytest.approx(1.0 + COMM), ["g:cuda"])
    assert greedy(sc, declared=True) == (pytest.approx(10.0), ["a"])
    assert greedy(gpu_pair(count=1), declared=True) == greedy(gpu_pair(count=1))  # nothing declared apart


def test_the_generator_is_deterministic_and_covers_every_kind() -> None:
    assert generate(7, seed=3) == generate(7, seed=3)
    assert generate(7, seed=3) != generate(7, seed=4)
    scenarios = [generate(i) for i in range(20)]
    assert [family_of(sc) for sc in scenarios[:5]] == list(FAMILIES)
    for sc in scenarios:
        team = sc.team()
        assert 2 <= len(team) <= 6 and any(r.accelerators for r in team)
        assert 1 <= len({p.origin for p in sc.programs}) <= 3 and sum(p.count for p in sc.programs) <= 16
        kind = family_of(sc)
        assert bool(sc.faults) == (kind in ("crash", "cut"))
        for f in sc.faults:  # an accelerator robot that submits nothing fails
            robot = next(r for r in team if r.name == f.robot)
            assert robot.accelerators and f.robot not in {p.origin for p in sc.programs}
        if kind != "misdeclared":
            assert all(p.accelerator_estimate is None for p in sc.programs)
        if kind != "strict":
            assert all(p.cpu_fallback for p in sc.programs)
    assert any(p.accelerator_estimate is not None for sc in scenarios if family_of(sc) == "misdeclared"
               for p in sc.programs)
    assert any(not p.cpu_fallback for sc in scenarios for p in sc.programs)
