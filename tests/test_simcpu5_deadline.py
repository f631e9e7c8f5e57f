"""The simulator hands a load report heard with no action to its node and
asks no deadline after it (``Simulator._deliver_report``): the wake it
scheduled stands. Checked after every report delivered in randomized
fault campaigns (crashes and recoveries, cuts, freezes, load changes)
and in a fleet with report fan-out: each hearer's wake is due no later
than its node's next deadline, and no silent hearing brings that
deadline forward."""

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


def due(node: Node) -> float:
    d = node.next_deadline()
    return math.inf if d is None else d


@pytest.fixture
def hearings(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """Count the silent hearings, failing on one that moves a deadline
    forward or that leaves a hearer's wake after its node's deadline."""
    handle, deliver = Node.handle, Simulator._deliver_report
    counted = [0]

    def checked(self: Node, event, now: float):
        before = due(self)
        out = handle(self, event, now)
        if not out and isinstance(event, Received) and isinstance(event.msg, LoadReport):
            assert due(self) >= before
            counted[0] += 1
        return out

    def delivered(self: Simulator, arg) -> None:
        deliver(self, arg)
        for dst in self._hearers(arg[0]):
            if dst.alive and not dst.frozen:
                assert dst.wake_at <= due(dst.node)

    monkeypatch.setattr(Node, "handle", checked)
    monkeypatch.setattr(Simulator, "_deliver_report", delivered)
    return counted


@pytest.mark.parametrize("seed", range(6))
def test_a_report_heard_with_no_action_leaves_the_wake_due(hearings: list[int], seed: int) -> None:
    sc = random_scenario(random.Random(seed), seed, "ramps", load_changes=seed % 2 == 1)
    assert Simulator(sc).run().lost == 0
    assert hearings[0] > 100


@pytest.mark.parametrize("policy", ["ramps", "round_robin"])
def test_in_a_fleet_with_fanout_too(hearings: list[int], policy: str) -> None:
    cfg = RampsConfig(heartbeat_period=5, heartbeat_timeout=15, report_fanout=4, placement_sample=16)
    res = Simulator(large_team(80, 400, 8, config=cfg, report_period=5), policy=policy).run()
    assert res.completed == 400 and hearings[0] > 1000
