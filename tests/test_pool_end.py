"""``RampsConfig.place_by``: a host costs when the program itself would end
there ("own_end", eq. 1 as published) or when the last program of that
host's pool would end, the new one included ("pool_end", the default).
Where a program that ends first on a busy host delays the program already
there, the pool-end rule sends it elsewhere and the team ends sooner; where
it delays no one, both rules place alike (docs/lab/2026-11-27-pool-end.md)."""

from __future__ import annotations

import random

import pytest

from ramps.core.burst import plan
from ramps.core.config import RampsConfig
from ramps.core.cost import pool_finish_time, shared_finish_time
from ramps.core.loadview import LoadView
from ramps.core.policy import PlacementRequest, Pool, RampsPolicy
from ramps.sim.engine import simulate
from ramps.sim.scenario import ProgramSpec, RobotSpec, Scenario

from corehelpers import NET, report


def _busy_fast_robot(place_by: str | None, *, deadline: float | None = None) -> Scenario:
    """b (one core, speed 2) runs its own 20-unit program (10 s); a second
    later a (one core, speed 0.8) submits 4 units: 4 s on b beside b's
    program, which it delays by 2 s, or 5 s alone on a."""
    config = RampsConfig() if place_by is None else RampsConfig(place_by=place_by)  # type: ignore[arg-type]
    return Scenario(name="pool-end", config=config,
                    robots=[RobotSpec(name="a", cores=1, speed=0.8), RobotSpec(name="b", cores=1, speed=2.0)],
                    programs=[ProgramSpec(origin="b", count=1, work=20.0),
                              ProgramSpec(origin="a", count=1, work=4.0, at=1.0, deadline=deadline)])


def test_the_pool_end_rule_leaves_a_busy_host_to_its_program_and_the_team_ends_sooner() -> None:
    own = simulate(_busy_fast_robot("own_end"), policy="ramps", seed=1)
    pool = simulate(_busy_fast_robot("pool_end"), policy="ramps", seed=1)
    assert (own.completed, own.lost, pool.completed, pool.lost) == (2, 0, 2, 0)
    assert {p.origin: p.host for p in own.programs} == {"a": "b", "b": "b"}  # 4 s there against 5 s at home
    assert {p.origin: p.host for p in pool.programs} == {"a": "a", "b": "b"}  # b's pool would end 2 s later
    assert pool.makespan < own.makespan * 0.9
    assert pool.makespan == pytest.approx(10.0, rel=0.01)  # b's program alone: 20 units at speed 2


def test_on_by_default_and_a_program_with_a_deadline_is_placed_by_its_own_end() -> None:
    assert RampsConfig().place_by == "pool_end"
    default = simulate(_busy_fast_robot(None), policy="ramps", seed=1, trace=True)
    pool = simulate(_busy_fast_robot("pool_end"), policy="ramps", seed=1, trace=True)
    assert default.trace == pool.trace and default.makespan == pool.makespan
    own = simulate(_busy_fast_robot("own_end", deadline=30.0), policy="ramps", seed=1, trace=True)
    pool = simulate(_busy_fast_robot("pool_end", deadline=30.0), policy="ramps", seed=1, trace=True)
    assert own.trace == pool.trace  # best fit decides; the option changes nothing


def test_programs_alike_are_placed_alike_by_either_rule() -> None:
    """A program no smaller than those already on a pool and started no
    earlier ends last there: its own end is the pool's (the paper's
    experiments and the several-origins sweep, whose programs are alike,
    give the same figures by either rule)."""
    def team(place_by: str) -> Scenario:
        return Scenario(name="alike", config=RampsConfig(place_by=place_by),  # type: ignore[arg-type]
                        robots=[RobotSpec(name="a", cores=2, speed=1.0), RobotSpec(name="b", cores=1, speed=2.0),
                                RobotSpec(name="c", cores=4, speed=0.5, background=2)],
                        programs=[ProgramSpec(origin="a", count=5, work=20.0, spacing=0.05),
                                  ProgramSpec(origin="c", count=4, work=20.0, at=3.0, spacing=0.5)])
    own = simulate(team("own_end"), policy="ramps", seed=3, trace=True)
    pool = simulate(team("pool_end"), policy="ramps", seed=3, trace=True)
    assert own.completed == pool.completed == 9
    assert own.trace == pool.trace


def _choose(view: LoadView, place_by: str, work: float = 4.0) -> str:
    req = PlacementRequest(program_id="x", work=work, payload_size=1000, result_size=1000)
    config = RampsConfig(place_by=place_by)  # type: ignore[arg-type]
    return RampsPolicy().choose(req, view, 0.5, random.Random(0), net=NET, config=config).host


def test_idle_hosts_cost_the_same_by_either_rule() -> None:
    view = LoadView("o", cores=1, speed=0.8)
    view.on_report(report("o", cores=1, speed=0.8), 0.5)
    view.on_report(report("b", cores=1, speed=2.0), 0.5)
    assert _choose(view, "own_end") == _choose(view, "pool_end") == "b"


def test_a_pools_end_is_its_last_program_s() -> None:
    assert pool_finish_time(4.0, [], 1, 2.0) == shared_finish_time(4.0, [], 1, 2.0) == 2.0
    # 18 units left beside 4 new on one core of speed 2: both at 1/s for 4 s, then 14 at 2/s
    assert shared_finish_time(4.0, [18.0], 1, 2.0) == pytest.approx(4.0)
    assert pool_finish_time(4.0, [18.0], 1, 2.0) == pytest.approx(11.0)
    assert pool_finish_time(18.0, [4.0], 1, 2.0) == pytest.approx(11.0)


def test_a_bursts_plan_weighs_the_programs_already_on_a_pool() -> None:
    """Two 12.8-unit programs: one fast core (speed 2) where a teammate's
    burst put two 24.4-unit programs, or two idle slow cores (speed 0.5).
    On the fast core they end in 25.6 s, and the teammate's at 37.2 s; on
    the slow cores all end by 25.6 s."""
    fast = Pool(robot="fast", kind="", cores=1, speed=2.0, known=(24.4, 24.4), work=12.8)
    slow = Pool(robot="slow", kind="", cores=2, speed=0.5, work=12.8)
    options = [{("fast", ""): fast, ("slow", ""): slow} for _ in range(2)]
    where, ends = plan(options)
    assert where == [("fast", ""), ("fast", "")]
    where, ends = plan(options, whole=True)
    assert where == [("slow", ""), ("slow", "")]
    assert max(ends.values()) == pytest.approx(25.6)
