"""The origin's own robot, where a whole core is free for a program, ties
with a teammate that would end it only a little sooner
(``ramps.core.policy.HOME_MARGIN``), and the tie is broken as any (least
utilised, then this robot): the teammate's core is what the other
origins' next programs draw on, and an origin cannot see them coming
(docs/lab/2026-11-27-battery-gap.md)."""

from __future__ import annotations

import random

from ramps.core.config import RampsConfig
from ramps.core.loadview import LoadView
from ramps.core.policy import HOME_MARGIN, PlacementRequest, RampsPolicy
from ramps.sim.engine import simulate
from ramps.sim.scenario import ProgramSpec, RobotSpec, Scenario

from corehelpers import NET, report


def _two_origins(r2_speed: float) -> Scenario:
    """r1 (2 cores) submits one program; a second later r2 (1 core, a little
    or much faster) submits its own."""
    return Scenario(name="home", robots=[RobotSpec(name="r1", cores=2, speed=1.0),
                                         RobotSpec(name="r2", cores=1, speed=r2_speed)],
                    programs=[ProgramSpec(origin="r1", count=1, work=20.0),
                              ProgramSpec(origin="r2", count=1, work=20.0, at=1.0)])


def test_a_program_stays_on_its_origins_free_core_when_a_teammate_is_a_little_faster() -> None:
    """r2 is 4% faster: r1's program on r2 would end 0.8 s sooner, and r2's
    own program a second later then shares r2's one core or goes to r1; the
    team ends later either way. Kept at home (a tie, and r1 the less
    utilised), each robot runs its own program alone."""
    res = simulate(_two_origins(1.04), policy="ramps", seed=1)
    assert (res.completed, res.lost, res.duplicated) == (2, 0, 0)
    assert {p.origin: p.host for p in res.programs} == {"r1": "r1", "r2": "r2"}
    alone = max(20.0 / 1.0, 1.0 + 20.0 / 1.04)  # each on its own core from its release
    assert res.makespan <= alone * 1.01


def test_a_clearly_faster_teammate_still_gets_the_program() -> None:
    """Beyond the margin the program goes where it ends first, as before."""
    res = simulate(_two_origins(1.5), policy="ramps", seed=1)
    hosts = {p.origin: p.host for p in res.programs}
    assert hosts["r1"] == "r2"


def _choose(view: LoadView, config: RampsConfig = RampsConfig(), deadline: float | None = None) -> str:
    req = PlacementRequest(program_id="x", work=20.0, payload_size=1000, result_size=1000, deadline=deadline)
    return RampsPolicy().choose(req, view, 0.5, random.Random(0), net=NET, config=config).host


def test_the_home_margin_needs_a_whole_free_core_and_no_deadline() -> None:
    view = LoadView("o", cores=2, speed=1.0)
    view.on_report(report("o", cores=2), 0.5)
    view.on_report(report("b", cores=2, speed=1.0 + HOME_MARGIN / 2), 0.5)
    assert _choose(view) == "o"  # a free core, within the margin: tied, equally utilised, home
    assert _choose(view, RampsConfig(energy_weight=0.5)) == "b"  # ranked by energy: no margin
    view.on_report(report("o", seq=2, cores=2, ramps_running=2, runnable=2.0, ramps_avg=2.0, cpu_busy=2.0,
                          accepted_total=2, remaining=[30.0, 30.0]), 0.5)
    assert _choose(view) == "b"  # no free core at home: where it ends first
