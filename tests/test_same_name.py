"""Two nodes under one robot name (machines cloned from one disk image share
their host name, the default name): one of them leaves with a clear error,
the same one whichever hears the other first; a restarted node's previous
process, whose last report may still be on its way, is not a clash. The
real driver and core over the in-memory transport."""

from __future__ import annotations

import pytest

from ramps.runtime.node import NodeRuntime
from ramps.runtime.settings import load_settings
from ramps.testing.memory import MemoryPool, MemoryTeam, StillSampler


def clone(team: MemoryTeam, robot: str, incarnation: int) -> NodeRuntime:
    """A second node named ``robot``, on its own transport."""
    s = load_settings(flags={"robot": robot, "team": team.team, "cores": 2, "speed": 1.0}, environ={})
    rt = NodeRuntime(s, transport=team.bus.transport(f"{robot}-clone"), clock=team.clock, worker_pool=MemoryPool,
                     load_sampler=StillSampler, incarnation=incarnation)
    rt.start(threaded=False)
    team.nodes[f"{robot}-clone"] = rt
    return rt


@pytest.mark.parametrize("clone_incarnation, leaves", [(99, "clone"), (1, "first")])
def test_two_nodes_with_one_name_one_leaves_and_says_why(clone_incarnation, leaves, caplog):
    team = MemoryTeam({"r1": (2, 1.0), "r2": (2, 1.0)})  # r2's incarnation is 2
    try:
        team.run(3.0)
        first, other = team.nodes["r2"], clone(team, "r2", clone_incarnation)
        team.run(5.0)
        gone, stays = (other, first) if leaves == "clone" else (first, other)
        assert gone.wait(0) and "robot name 'r2' is used by two nodes of team 'mem'" in gone.name_taken
        assert "give each robot its own name" in gone.name_taken
        assert not stays.wait(0) and stays.name_taken == ""
        assert any("leaves the team" in r.getMessage() for r in caplog.records)
    finally:
        team.close()


def test_the_last_report_of_a_previous_process_is_not_a_clash():
    team = MemoryTeam({"r1": (2, 1.0), "r2": (2, 1.0)})
    try:
        team.run(3.0)
        old = team.nodes["r2"]
        report = old._last_report
        team.kill("r2")
        new = team.add("r2", seed=5)  # the supervisor's restart: a new incarnation
        from ramps.core.messages import encode
        from ramps.runtime import keys

        team.bus.transport("stray").put(keys.load(team.team, "r2"), encode("r2", report))  # still on its way
        team.run(5.0)
        assert new._same_name_seen == {report.incarnation: report.seq}  # heard, and not taken for a clash
        assert not new.wait(0) and new.name_taken == ""
    finally:
        team.close()
