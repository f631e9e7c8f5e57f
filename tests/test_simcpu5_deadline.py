"""The simulator hands a load report heard with no action to its node and
schedules no wake for it (``Simulator._deliver_report``): such a hearing
never brings the node's next deadline forward. Checked on every hearing of
randomized fault campaigns (crashes, cuts, freezes, load changes) and of a
fleet with report fan-out."""

from __future__ import annotations

import math
import random

import pytest

from ramps.bench.simulator import large_team
from ramps.core.config import RampsConfig
from ramps.core.events import Received
from ramps.core.messages import LoadReport
from ramps.core.node import Node
from ramps.experiments.campaign import random_scenario
from ramps.sim.engine import Simulator


@pytest.fixture
def hearings(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """Count the silent hearings, failing on one that moves a deadline forward."""
    handle = Node.handle
    counted = [0]

    def checked(self: Node, event, now: float):
        before = self.next_deadline()
        out = handle(self, event, now)
        if not out and isinstance(event, Received) and isinstance(event.msg, LoadReport):
            after = self.next_deadline()
            assert (math.inf if after is None else after) >= (math.inf if before is None else before)
            counted[0] += 1
        return out

    monkeypatch.setattr(Node, "handle", checked)
    return counted


@pytest.mark.parametrize("seed", range(6))
def test_a_report_heard_with_no_action_sets_no_earlier_deadline(hearings: list[int], seed: int) -> None:
    sc = random_scenario(random.Random(seed), seed, "ramps", load_changes=seed % 2 == 1)
    assert Simulator(sc).run().lost == 0
    assert hearings[0] > 100


def test_in_a_fleet_with_fanout_too(hearings: list[int]) -> None:
    cfg = RampsConfig(heartbeat_period=5, heartbeat_timeout=15, report_fanout=4, placement_sample=16)
    res = Simulator(large_team(80, 400, 8, config=cfg, report_period=5)).run()
    assert res.completed == 400 and hearings[0] > 1000
