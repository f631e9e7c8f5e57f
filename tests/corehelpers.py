"""Shared helpers for the pure core tests (see ramps.testing.FakeTeam)."""

from __future__ import annotations

import random


from ramps.core.config import RampsConfig
from ramps.core.cost import NetworkEstimate
from ramps.core.events import (
    Submit,
)
from ramps.core.loadview import LoadView
from ramps.core.messages import (
    LoadReport,
)
from ramps.core.policy import PlacementRequest

from ramps.testing import FakeTeam as Team

CFG = RampsConfig()
NET = NetworkEstimate()


def report(robot: str, seq: int = 1, **kw) -> LoadReport:
    fields = dict(robot=robot, incarnation=0, seq=seq, cores=4, speed=1.0, cpu_busy=0.0, runnable=0.0,
                  ramps_running=0, ramps_avg=0.0, accepted_total=0, finished_total=0)
    fields.update(kw)
    return LoadReport(**fields)


def busy_origin_team(**kw) -> Team:
    """Origin ``o`` is swamped (1 core, 10 background tasks), so its programs
    go out: to ``a`` (fastest) first, then ``b``."""
    team = Team({"o": (1, 1.0), "a": (4, 2.0), "b": (4, 1.0)}, **kw)
    team.nodes["o"].executor.background = 10.0
    team.publish()
    return team


def submit(team: Team, pid: str = "p", program: str = "route_plan", **kw) -> None:
    team.handle("o", Submit(program_id=pid, program=program, work=kw.pop("work", 50.0), **kw))


def choose(policy, view: LoadView, *, seed: int = 0, now: float = 1.0, work: float = 53.0,
           exclude: frozenset[str] = frozenset(), rng: random.Random | None = None) -> str:
    req = PlacementRequest(program_id="x", work=work, payload_size=1000, result_size=1000)
    return policy.choose(req, view, now, rng or random.Random(seed), net=NET, config=CFG, exclude=exclude).host


def view_of(me: str, *reports: LoadReport, cores: int = 4, speed: float = 1.0) -> LoadView:
    view = LoadView(me, cores=cores, speed=speed)
    for rep in reports:
        view.on_report(rep, 0.5)
    return view
