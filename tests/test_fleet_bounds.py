"""Fleets: what a robot sends and an origin keeps stays bounded as the team
grows (``ramps.core.fanout`` where a team sets ``report_fanout``,
``Links.probes``), and teams of at most ``placement_sample`` robots are
untouched."""

from __future__ import annotations

from collections import Counter

import msgspec

from ramps.core.config import RampsConfig
from ramps.core.cost import NetworkEstimate
from ramps.core.events import Send
from ramps.core.fanout import report_order, report_targets
from ramps.core.links import Links
from ramps.core.messages import LinkProbe
from ramps.sim.engine import Simulator
from ramps.sim.scenario import ProgramSpec, RobotSpec, Scenario

CFG = msgspec.structs.replace(RampsConfig(), report_fanout=16)


def test_a_small_team_or_few_origins_report_to_every_origin() -> None:
    origins = [f"w{i}" for i in range(1, 41)]
    assert report_targets("w50", origins, CFG.placement_sample, CFG) is None  # 64 robots: all
    assert report_targets("w50", origins[:CFG.report_fanout], 10_000, CFG) is None  # 16 others: all
    assert report_targets("w50", origins, 10_000, RampsConfig()) is None  # off unless a team sets it


def test_in_a_fleet_each_robot_reports_to_the_same_few_origins_and_each_origin_hears_its_share() -> None:
    cfg = msgspec.structs.replace(CFG, report_fanout=4)
    origins = [f"w{i}" for i in range(1, 21)]
    robots = [f"w{i}" for i in range(1, 1001)]
    heard: Counter[str] = Counter()
    for robot in robots:
        targets = report_targets(robot, origins, len(robots), cfg)
        assert targets is not None and len(targets) == 4 and robot not in targets
        assert targets == report_targets(robot, list(reversed(origins)), len(robots), cfg)  # names alone decide
        heard.update(targets)
    assert set(heard) == set(origins)
    share = 4 * len(robots) / len(origins)  # 200 robots per origin
    assert all(0.75 * share < n < 1.25 * share for n in heard.values()), heard


def test_an_origin_that_leaves_moves_only_the_robots_that_reported_to_it() -> None:
    cfg = msgspec.structs.replace(CFG, report_fanout=4)
    origins = [f"w{i}" for i in range(1, 21)]
    for r in (f"w{i}" for i in range(1, 501)):
        before, after = report_order(r, origins, 500, cfg), report_order(r, origins[1:], 500, cfg)
        assert before is not None and after is not None
        assert after == [o for o in before if o != "w1"]  # every other origin keeps its place
        first, then = report_targets(r, origins, 500, cfg) or [], report_targets(r, origins[1:], 500, cfg) or []
        if "w1" not in first:
            assert then == first


def test_probes_go_to_every_candidate_in_a_small_team_and_in_turn_in_a_large_one() -> None:
    links = Links(NetworkEstimate())
    small = [f"r{i}" for i in range(10)]
    sent = links.probes(small, "r0", 0.0, 64)
    assert [a.to for a in sent] == small[1:] and all(isinstance(a.msg, LinkProbe) for a in sent)
    large = [f"r{i}" for i in range(200)]
    probed: Counter[str] = Counter()
    for period in range(4):
        sent = links.probes(large, "r0", 5.0 * (period + 1), 64)
        assert len(sent) == 64 and all(isinstance(a, Send) for a in sent)
        probed.update(a.to for a in sent)
    assert set(probed) == set(large[1:])  # 199 links, 64 a period: all within four periods
    assert max(probed.values()) <= 2


def fleet(robots: int, origins: int, fanout: int) -> Scenario:
    cfg = msgspec.structs.replace(CFG, report_fanout=fanout)
    return Scenario(name="fleet", seed=2, config=cfg,
                    robots=[RobotSpec(name="w{i}", count=robots, cores=2, speed=1.0)],
                    programs=[ProgramSpec(count=6, work=8.0, origin=f"w{i + 1}", at=0.5 * i, spacing=0.1)
                              for i in range(origins)])


def test_a_fleet_origin_hears_and_places_on_its_share_and_every_program_completes() -> None:
    sim = Simulator(fleet(100, 12, 4))
    res = sim.run()
    assert res.completed == 72 and res.lost == 0 and res.duplicated == 0
    for i in range(1, 13):
        me = f"w{i}"
        heard = {r for r in sim.names if r == me or me in (report_targets(r, sim.subscribers, 100, sim.sc.config)
                                                           or sim.subscribers)}
        assert set(sim.robots[me].node.view.robots()) <= heard and len(heard) < 100
    assert len({p.host for p in res.programs}) > 12  # placed across the team, not only on the origins


def test_the_same_fleet_and_seed_give_the_same_run() -> None:
    a, b = Simulator(fleet(100, 12, 3)).run(), Simulator(fleet(100, 12, 3)).run()
    assert [(p.program_id, p.host, p.delivered_at) for p in a.programs] == \
        [(p.program_id, p.host, p.delivered_at) for p in b.programs]
    assert a.events == b.events
