"""``ramps bench team-size``: its figures come from a real team, and its
judgement of "survivors hear each other" reads the team's status rightly.

The end-to-end test runs the whole measurement on a team of five real
nodes (one idle second, a burst of 10 small programs from three origins,
one robot killed during a second burst) and checks what the benchmark
reports against what must be true of any run: every program came back once
(the robots' own run counters agree), the killed robot's programs came back
too, the survivors were heard again. No figure is compared with a target.
"""

from __future__ import annotations

import pytest

from ramps.bench.teamsize import hears, late, lo_counters, measure_size
from ramps.runtime.futures import RobotStatus, TeamStatus


class _Client:
    def __init__(self, rows: list[RobotStatus]) -> None:
        self.rows = rows

    def status(self) -> TeamStatus:
        return TeamStatus(team="t", robots=self.rows)


def _row(robot: str, sees: int | None, age: float | None = 0.5, alive: bool = True) -> RobotStatus:
    return RobotStatus(robot=robot, alive=alive, sees=sees, report_age=age)


def test_survivors_are_heard_only_when_each_sees_exactly_the_others_freshly():
    survivors = {"r1", "r2", "r3"}
    assert hears(_Client([_row("r1", 2), _row("r2", 2), _row("r3", 2), _row("r4", None, alive=False)]), survivors)
    assert not hears(_Client([_row("r1", 2), _row("r2", 3), _row("r3", 2)]), survivors)  # still counts the dead
    assert not hears(_Client([_row("r1", 2), _row("r2", 2), _row("r3", 2, age=4.0)]), survivors)  # stale report
    assert not hears(_Client([_row("r1", 2), _row("r2", 2)]), survivors)  # one not heard at all
    assert not hears(_Client([_row("r1", 2), _row("r2", 2), _row("r3", 2, alive=False)]), survivors)


def test_a_late_survivor_is_named_with_why():
    survivors = {"r1", "r2", "r3"}
    client = _Client([_row("r1", 2), _row("r2", 3), _row("r3", 2, age=4.0)])
    assert late(client, survivors) == {"r2": "sees 3 of 2", "r3": "report 4.0 s old"}
    assert late(_Client([_row("r1", 2), _row("r2", 2)]), survivors) == {"r3": "not seen alive"}
    assert late(_Client([_row("r1", 2), _row("r2", 2), _row("r3", 2)]), survivors) == {}


def test_loopback_counters_read_this_namespace():
    rx_bytes, rx_packets = lo_counters()
    assert rx_bytes >= 0 and rx_packets >= 0


@pytest.mark.slow
def test_a_real_team_measured_end_to_end():
    res = measure_size(5, idle=1.0, units=0.2, kill_at=0.3, form_timeout=60.0, burst_timeout=60.0, settle=0.0,
                       log=lambda s: None)
    assert res["formed_s"] is not None and res["formed_s"] > 0
    idle = res["idle"]
    assert idle["pss_mib"]["median"] >= idle["node_and_fork_server_pss_mib"]["median"] \
        > idle["node_pss_mib"]["median"] > 0 and idle["threads"]["median"] > 0
    assert idle["node_cpu_pct"]["median"] >= 0 and idle["lo_bytes_per_node_s"] > 0
    burst = res["burst"]
    assert burst["delivered"] == burst["programs"] == 10 and burst["failed"] == 0
    assert burst["runs_counted"] == burst["delivered"]  # once each: the robots ran no program twice
    assert sum(burst["per_robot"].values()) == 10
    kill = res["kill"]
    assert kill["killed"] == 1 and kill["during_burst"], kill
    assert kill["delivered"] == kill["programs"] == 10, kill  # nothing lost with a robot killed mid-burst
    assert kill["heard_s_after_kill"] is not None
