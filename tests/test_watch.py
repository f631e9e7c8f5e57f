"""ramps.runtime.watch.TeamWatcher on a real two-robot team: it sees both
robots alive with their load reports, and the moment one is killed."""

from __future__ import annotations

import json
import time

import pytest

from ramps.runtime.watch import TeamWatcher
from runtime_team import LocalTeam, assert_no_leftovers, wait_for

pytestmark = pytest.mark.slow


def _config(endpoints: list[str]):
    import zenoh

    c = zenoh.Config()
    c.insert_json5("mode", '"peer"')
    c.insert_json5("listen/endpoints", "[]")
    c.insert_json5("connect/endpoints", json.dumps(endpoints))
    c.insert_json5("scouting/multicast/enabled", "false")
    return c


def test_the_watcher_sees_robots_their_reports_and_a_crash(tmp_path):
    with LocalTeam(2, tmp_path) as t:
        with TeamWatcher.open(_config(t.endpoints()), t.team) as w:
            assert wait_for(lambda: w.ready() == {"r1", "r2"}, 15, "both robots alive with a load report")
            rows = {r["robot"]: r for r in w.view()}
            assert rows["r1"]["alive"] and rows["r1"]["cores"] == 2 and rows["r2"]["report_age"] >= 0
            assert w.report("r2").robot == "r2" and w.bad_messages("r1") == 0
            assert w.wait("r2", True, 1.0) is not None  # already alive: now
            killed = time.monotonic()
            t.kill_node("r2")
            gone = w.wait("r2", False, 15.0, since=killed)
            assert gone is not None and gone - killed < 5.0  # a crash: the TCP reset, well within the lease
            assert "r2" not in w.ready() and w.report("r1") is not None
    assert_no_leftovers()
