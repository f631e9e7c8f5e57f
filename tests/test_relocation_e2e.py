"""A program that checkpoints survives its host on real node processes: the
host is killed mid-run, the origin restarts the program on a teammate from
its latest checkpoint (``ramps.resume()``), and the one result says so."""

from __future__ import annotations

import pytest
from runtime_team import PROGRAMS, LocalTeam, assert_no_leftovers, wait_for

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module", autouse=True)
def no_leftover_processes():
    yield
    assert_no_leftovers()


def test_a_checkpointing_program_resumes_on_a_teammate_after_its_host_dies(tmp_path):
    with LocalTeam(2, tmp_path, cores=2, programs=PROGRAMS + ("resumable",)) as t:
        team = t.client("r1")
        rr = team.options(policy="round_robin")
        here = rr.submit("resumable", steps=40, dt=0.1)  # round robin: the first runs on the origin ...
        there = rr.submit("resumable", steps=40, dt=0.1)  # ... the second on r2
        wait_for(lambda: there.host == "r2" and (there.progress or 0) >= 0.25, 30,
                 f"the program running on r2 a quarter through ({t.logs()})")
        t.kill_node("r2")
        out = there.result(timeout=60)
        assert out["robot"] == "r1" and out["first"] >= 10, out
        assert there.resumed_from is not None and there.resumed_from >= 0.25 and there.attempts == 2
        assert here.result(timeout=60) == {"robot": "r1", "first": 0} and here.resumed_from is None
