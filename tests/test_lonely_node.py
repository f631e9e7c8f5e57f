"""A node told to --connect somewhere (or with multicast off) that hears no
teammate in its first seconds says so once, with what it tried and what to
check, and runs on; one that hears a teammate says nothing."""

from __future__ import annotations

import logging

from ramps.runtime.node import LONELY_AFTER
from ramps.testing.memory import MemoryTeam

ALONE = {"multicast": False, "connect": ["tcp/10.9.9.9:7447"]}


def test_a_node_that_hears_nobody_says_what_it_tried_and_runs_on(caplog):
    team = MemoryTeam({"r1": (2, 1.0)}, settings=ALONE)
    try:
        with caplog.at_level(logging.WARNING, logger="ramps.node"):
            team.run(LONELY_AFTER - 1.0)
            assert team.nodes["r1"].inbound.lonely == ""  # not before its first seconds
            team.run(3.0)
        rt = team.nodes["r1"].inbound  # what it heard, and the warning it gave
        assert "heard no teammate in team 'mem'" in rt.lonely
        assert "connecting to tcp/10.9.9.9:7447" in rt.lonely and "multicast discovery off" in rt.lonely
        assert "--connect names an endpoint a teammate's node listens on" in rt.lonely and "--no-multicast" in rt.lonely
        assert [r.getMessage() for r in caplog.records].count(rt.lonely) == 1
        team.run(30.0)
        assert [r.getMessage() for r in caplog.records].count(rt.lonely) == 1  # once
        app = team.connect("r1")  # a lone robot still runs programs
        fut = app.submit("echo", x=1)
        team.run(1.0, until=fut.done)
        assert fut.result(0) == {"x": 1}
        app.close()
    finally:
        team.close()


def test_a_node_with_a_teammate_says_nothing():
    team = MemoryTeam({"r1": (2, 1.0), "r2": (2, 1.0)}, settings=ALONE)
    try:
        team.run(LONELY_AFTER + 5.0)
        assert team.nodes["r1"].inbound.lonely == "" and team.nodes["r2"].inbound.lonely == ""
    finally:
        team.close()
