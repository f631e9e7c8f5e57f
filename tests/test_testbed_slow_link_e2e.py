"""A program's 5 MB of parameters cross a slow link whole, on real
node processes in the testbed (ramps.runtime.bulk; tc tbf at 1 MB/s).

Zenoh's DROP congestion control dropped such a message whenever the link
could not take it at once, so the origin's offer timed out and the program
ran on the busy origin instead. Needs root and cgroup v1 (skipped otherwise)."""

from __future__ import annotations

import json

import pytest

from test_testbed import REASON, others_leftovers, wait_until

from ramps.runtime.localteam import cgroup_mode

pytestmark = [pytest.mark.slow, pytest.mark.serial,  # busy processes and a shaped link: run alone
              pytest.mark.skipif(REASON is not None or cgroup_mode() != "v1",
                                 reason=REASON or "the testbed's caps need cgroup v1")]


def test_a_5_mb_offer_over_a_1_mb_s_link_is_accepted_at_the_first_attempt():
    from ramps.testbed import Testbed
    from ramps.lab.experiments import identical_speed
    from ramps.testbed.slowlink import TARGET, slow_link

    before = others_leftovers()
    quota = 0.3
    with Testbed(["r1", "r2"], cores=4, quota=quota, speed=identical_speed(1, 4, quota), programs=[TARGET]) as tb, \
            tb.client("r1", timeout=60.0) as team:
        slow_link(tb, "r2", 1e6)
        tb.add_load("r1", 8)  # r1 is busy: its program is worth sending to r2, slow link and all
        assert wait_until(lambda: any(r.robot == "r1" and r.runnable >= 6 for r in team.status().robots), 30)
        # declared 0.3 units (what placement weighs against the transfer), it burns 0.05 (how
        # long it then runs on r2 is not what this test checks)
        fut = team.options(work=0.3).submit("crunch", data=b"\x5a" * 5_000_000, units=0.05)
        assert fut.result(timeout=120) == {"bytes": 5_000_000}
        assert tb.log_dir is not None
        trace = [json.loads(line) for line in (tb.log_dir / "r1.trace.jsonl").read_text().splitlines()]
        placed = [(e["what"], e["other"], e["detail"]) for e in trace if e["what"] in ("placed", "failed")]
        assert fut.host == "r2" and fut.attempts == 1, placed
    assert others_leftovers() == before
