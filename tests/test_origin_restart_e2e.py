"""An origin's node killed (SIGKILL) with programs in flight and started
again by its supervisor, on real processes: the restarted node resumes
every program from its durable record, hosts that kept running theirs
deliver to it, the programs that ran on the dead node run again, and the
client that waited through it gets every outcome once. The driver logic
in milliseconds: tests/test_origin_restart.py."""

from __future__ import annotations

import time

import pytest
from runtime_team import LocalTeam

pytestmark = pytest.mark.slow  # three real nodes, one killed and started again: 10-20 s


def test_an_origin_killed_and_restarted_by_its_supervisor_loses_nothing(tmp_path):
    with LocalTeam(3, tmp_path) as t:
        client = t.client("r1", origin_grace=60.0)
        rr = client.options(policy="round_robin")
        futs = [rr.submit("sleepy", seconds=5.0, tag=f"p{i}") for i in range(6)]
        deadline = time.monotonic() + 30
        while any(f.state != "running" for f in futs) and time.monotonic() < deadline:
            time.sleep(0.1)
        placed = {f: f.host for f in futs}
        assert set(placed.values()) == {"r1", "r2", "r3"}, placed  # round robin: two on each
        t.kill_node("r1")
        time.sleep(2.0)  # a supervisor's restart delay
        t.start_node("r1")
        results = [f.result(60) for f in futs]
        assert sorted(r["tag"] for r in results) == [f"p{i}" for i in range(6)]
        for f, r in zip(futs, results):
            if placed[f] == "r1":  # its copy died with the node: placed again from the record
                assert f.attempts == 2, (placed[f], r, f.attempts)
            else:  # its host kept it running and delivered it to the new node
                assert (f.attempts, r["robot"]) == (1, placed[f]), (placed[f], r, f.attempts)
        assert "resumed 6 program(s) from its record" in (tmp_path / "r1.log").read_text()
