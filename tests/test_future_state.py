"""``ProgramFuture.state`` says how a program ended, and ``moves`` counts
relocations only: the real client and nodes over the in-memory team
(``ramps.testing.memory``), in milliseconds."""

from __future__ import annotations

from concurrent.futures import CancelledError

import pytest

from ramps.errors import ProgramFailed
from ramps.testing.memory import MemoryTeam


@pytest.fixture
def team():
    t = MemoryTeam({"r1": (1, 1.0), "r2": (4, 4.0), "r3": (4, 4.0)}, programs=["e2eprogs:fail"])
    t.run(3.0)  # everyone has heard everyone's reports
    client = t.connect("r1")
    yield t, client
    client.close()
    t.close()


def test_state_is_done_or_failed_with_the_outcome(team):
    t, client = team
    ok, bad = client.submit("echo", x=1), client.submit("fail")
    t.run(10.0, until=lambda: ok.done() and bad.done())
    assert ok.result(0) == {"x": 1} and ok.state == "done"
    with pytest.raises(ProgramFailed, match="no route to the dock"):
        bad.result(0)
    assert bad.state == "failed"


def test_a_cancelled_future_says_cancelled(team):
    t, client = team
    fut = client.options(work=20.0).submit("echo", x=1)
    t.run(2.0, complete=False, until=lambda: fut.state == "running")
    assert fut.state == "running"
    assert fut.cancel()
    with pytest.raises(CancelledError):
        fut.result(0)
    assert fut.state == "cancelled"
    t.run(1.0)  # the withdrawal reaches the team; the state stays
    assert fut.state == "cancelled"


def test_a_timed_out_future_says_timed_out(team):
    t, client = team
    fut = client.options(timeout=0.05, work=20.0).submit("echo", x=1)
    t.run(2.0, complete=False, until=lambda: fut.state == "running")
    assert fut.state == "running"
    t.run(1.0, complete=False)  # past the deadline on the team's clock: the client's timer withdraws it
    with pytest.raises(TimeoutError, match="did not finish in time"):
        fut.result(timeout=10)
    assert fut.state == "timed_out"


def test_a_failover_is_an_attempt_not_a_move(team):
    """``moves`` counts relocations of a program on a healthy host; a
    re-placement after its host died is one more attempt."""
    t, client = team
    fut = client.options(work=20.0).submit("echo", x=7)
    t.run(2.0, complete=False, until=lambda: any(t.pools[r].jobs for r in ("r2", "r3")))
    host = "r2" if t.pools["r2"].jobs else "r3"
    t.kill(host)
    t.run(30.0, until=fut.done)
    assert fut.result(0) == {"x": 7} and fut.state == "done"
    assert fut.host != host and fut.attempts == 2
    assert fut.moves == 0
