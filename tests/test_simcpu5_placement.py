"""Placement's kept figures (``ramps.core.links.Links.comm_times``, the
program's own end as its pool's in ``ramps.core.policy``) give the very
placements the figures made afresh give."""

from __future__ import annotations

import random

from ramps.core.config import RampsConfig
from ramps.core.cost import NetworkEstimate, comm_time
from ramps.core.links import Links
from ramps.core.loadview import LoadView
from ramps.core.messages import LinkProbeReply, LoadReport
from ramps.core.policy import PlacementRequest, RampsPolicy

DEFAULT = NetworkEstimate(latency=0.005, bandwidth=2.5e6)


def report(robot: str, running: int, remaining: list[float]) -> LoadReport:
    return LoadReport(robot=robot, incarnation=0, seq=1, cores=4, speed=1.0, cpu_busy=float(min(4, running)),
                      runnable=float(running), ramps_running=running, ramps_avg=float(running),
                      accepted_total=running, finished_total=0, remaining=remaining)


def measured(links: Links, robot: str, now: float, latency: float) -> None:
    probe = links.probe(robot, now)
    links.on_reply(robot, LinkProbeReply(sent_at=probe.sent_at, size=len(probe.padding)),
                   now + 2 * latency + len(probe.padding) / 1e6)


def test_comm_times_stand_until_the_links_figures_change() -> None:
    links = Links(DEFAULT)
    kept = links.comm_times(2000, 1000)
    kept["r2"] = comm_time(2000, 1000, links("r2"))
    assert links.comm_times(2000, 1000) is kept and links("r2") is DEFAULT
    measured(links, "r2", 0.0, 0.001)  # a reply: r2's figure goes, the others stay
    kept["r3"] = 1.0
    measured(links, "r2", 1.0, 0.001)
    assert "r2" not in links.comm_times(2000, 1000) and kept["r3"] == 1.0
    for size in range(20):  # a bounded number of sizes
        links.comm_times(size, 0)
    assert len(links._comm) <= 8


def team_view(seed: int) -> LoadView:
    rng = random.Random(seed)
    view = LoadView("w0", cores=4, speed=1.0)
    for i in range(1, 200):
        running = rng.randrange(0, 9)
        view.on_report(report(f"w{i}", running, sorted(rng.uniform(0.0, 60.0) for _ in range(running))), 0.5)
    return view


def test_placements_with_kept_figures_are_those_made_afresh() -> None:
    cfg = RampsConfig(placement_sample=64)
    for seed in range(5):
        links = Links(DEFAULT)
        for i in range(1, 200, 3):
            measured(links, f"w{i}", 0.0, 0.0005 * (i % 7 + 1))
        kept, fresh = RampsPolicy(), RampsPolicy()
        view_kept, view_fresh = team_view(seed), team_view(seed)
        rng_kept, rng_fresh = random.Random(seed), random.Random(seed)
        for n in range(40):
            req = PlacementRequest(program_id=f"p{n}", work=53.0 + (n % 3), payload_size=2000, result_size=1000)
            now = 1.0 + 0.05 * n
            a = kept.choose(req, view_kept, now, rng_kept, net=DEFAULT, config=cfg, links=links)
            b = fresh.choose(req, view_fresh, now, rng_fresh, net=DEFAULT, config=cfg, links=links.estimate)
            assert a == b
            for view, place in ((view_kept, a), (view_fresh, b)):
                view.book(place.host, req.program_id, 1)
            if n % 10 == 9:
                measured(links, a.host, now, 0.002)
