"""Large teams: ``ramps`` placement prices a short list of candidates
(``RampsConfig.placement_sample``) and still finds the cheapest host."""

from __future__ import annotations

import random

import msgspec

from corehelpers import CFG, NET, report, view_of
from ramps.core.config import RampsConfig
from ramps.core.loadview import LoadView
from ramps.core.policy import PlacementRequest, RampsPolicy

EXACT = msgspec.structs.replace(CFG, placement_sample=0)


def team_view(robots: int, seed: int) -> LoadView:
    rng = random.Random(seed)
    reps = [report(f"r{i}", ramps_running=(n := rng.randrange(0, 9)), runnable=float(n), ramps_avg=float(n),
                   cores=rng.choice((2, 4)), speed=rng.choice((1.0, 1.5)))
            for i in range(1, robots)]
    return view_of("r0", *reps)


def place(policy: RampsPolicy, view: LoadView, rng: random.Random, config: RampsConfig, now: float, pid: str):
    req = PlacementRequest(program_id=pid, work=53.0, payload_size=1000, result_size=1000)
    return policy.choose(req, view, now, rng, net=NET, config=config)


def test_a_team_no_larger_than_the_sample_places_as_the_full_scan() -> None:
    for seed in range(20):
        view = team_view(CFG.placement_sample, seed)
        a, b = random.Random(seed), random.Random(seed)
        assert place(RampsPolicy(), view, a, CFG, 1.0, "p") == place(RampsPolicy(), view, b, EXACT, 1.0, "p")
        assert a.random() == b.random()  # the same draws taken


def test_the_short_list_finds_a_cheapest_host_without_scanning_the_team(monkeypatch) -> None:
    view = team_view(400, seed=1)
    policy, rng = RampsPolicy(), random.Random(1)
    scans = {"full": 0, "short": 0}
    scan = LoadView.scan

    def counted(self, now, exclude, paper=False, only=None):
        scans["full" if only is None else "short"] += 1
        return scan(self, now, exclude, paper, only)

    monkeypatch.setattr(LoadView, "scan", counted)
    for i in range(300):
        now = 1.0 + i * 0.001
        picked = place(policy, view, rng, CFG, now, f"p{i}")
        best = place(RampsPolicy(), view, random.Random(i), EXACT, now, f"p{i}")
        assert picked.expected_time <= best.expected_time * (1.0 + CFG.tie_tolerance) + 1e-9
        view.book(picked.host, f"p{i}", 1)
    assert scans["short"] > 250 and scans["full"] - 300 < 50  # 300 of the full ones were the exact policy's
