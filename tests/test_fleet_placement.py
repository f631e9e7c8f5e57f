"""Large teams: when ``ramps`` placement's short list of candidates
(``RampsConfig.placement_sample``) falls and a full scan draws a new one."""

from __future__ import annotations

import random

from corehelpers import CFG, NET, report, view_of
from ramps.core.loadview import LoadView
from ramps.core.policy import PlacementRequest, RampsPolicy

ROBOTS = 400
FREE = 10  # robots with their one core free; every other teammate runs one program on it (this robot three)


def one_core_team() -> LoadView:
    reps = [report(f"r{i}", cores=1, ramps_running=0 if i <= FREE else 1, runnable=0.0 if i <= FREE else 1.0,
                   ramps_avg=0.0 if i <= FREE else 1.0) for i in range(1, ROBOTS)]
    return view_of("r0", report("r0", cores=1, ramps_running=3, runnable=3.0, ramps_avg=3.0), *reps)


def place_counting_scans(monkeypatch, placements: int) -> tuple[list[str], list[int]]:
    """The hosts of ``placements`` programs placed (and booked) one after
    another within a second, and the placements that scanned the whole view."""
    view, policy, rng = one_core_team(), RampsPolicy(), random.Random(3)
    full: list[int] = []
    scan = LoadView.scan

    def counted(self, now, exclude, paper=False, only=None):
        if only is None:
            full.append(len(hosts))
        return scan(self, now, exclude, paper, only)

    monkeypatch.setattr(LoadView, "scan", counted)
    hosts: list[str] = []
    for i in range(placements):
        req = PlacementRequest(program_id=f"p{i}", work=53.0, payload_size=1000, result_size=1000)
        picked = policy.choose(req, view, 1.0 + i * 0.001, rng, net=NET, config=CFG)
        view.book(picked.host, f"p{i}", 1)
        hosts.append(picked.host)
    return hosts, full


def test_the_list_falls_once_its_cheaper_robots_have_risen_to_the_next_level(monkeypatch) -> None:
    hosts, full = place_counting_scans(monkeypatch, FREE + 1)
    # the free cores go first, one program each, from the list drawn at the first placement
    assert sorted(hosts[:FREE], key=lambda h: int(h[1:])) == [f"r{i}" for i in range(1, FREE + 1)]
    # then every robot runs one: the list (the free ten and 54 of the others) falls, and the
    # next program is drawn from every robot at that level, not from the 54 listed alone
    assert full == [0, FREE]


def test_a_list_of_equals_stands_until_each_of_them_has_a_program_more(monkeypatch) -> None:
    sample = CFG.placement_sample
    hosts, full = place_counting_scans(monkeypatch, FREE + sample + 2)
    # the scan's own program goes where the whole view says, the next ones to the list
    listed = hosts[FREE + 1:FREE + 1 + sample]
    assert len(set(listed)) == sample  # one program more on each robot of the list of equals
    assert full == [0, FREE, FREE + 1 + sample]
