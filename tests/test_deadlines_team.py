"""Deadlines through the real client API (``team.options(deadline=...)``),
a real node driver on the in-memory team (``ramps.testing.memory``), and
the node's metrics. Time is the fake clock: nothing here depends on speed."""

from __future__ import annotations

import pytest

from ramps.errors import DeadlineUnmeetable
from ramps.testing import FakeTeam
from ramps.testing.memory import MemoryTeam

# workprogs.sized declares 0.5 work units per pick: 20 picks are 10 s on a speed-1 robot


@pytest.fixture
def team():
    t = MemoryTeam({"r1": (2, 1.0)}, programs=["workprogs:sized"])
    app = t.connect("r1")
    yield t, app
    app.close()
    t.close()


def test_a_deadline_met_and_one_missed(team) -> None:
    t, app = team
    in_time = app.options(deadline=30.0).submit("sized", picks=20)
    t.run(2.0, until=in_time.done)
    assert in_time.result(0) == 20 and in_time.missed_deadline is False
    late = app.options(deadline=15.0).submit("sized", picks=20)
    t.run(20.0, complete=False)  # the program takes longer than its deadline
    t.run(2.0, until=late.done)
    assert late.result(0) == 20 and late.missed_deadline is True  # a late result is still a result
    assert t.nodes["r1"].node.origin.deadline_misses == 1


def test_on_miss_fail_raises_deadline_unmeetable_before_anything_runs(team) -> None:
    t, app = team
    fut = app.options(deadline=1.0, on_miss="fail").submit("sized", picks=20)
    t.run(2.0, until=fut.done)
    with pytest.raises(DeadlineUnmeetable, match=r"cannot meet its deadline: expected 10\.00 s at best \(on r1\)"):
        fut.result(0)
    assert fut.missed_deadline is True
    assert t.pools["r1"].ran == []


def test_on_miss_run_and_local_still_run(team) -> None:
    t, app = team
    futs = [app.options(deadline=1.0, on_miss=m).submit("sized", picks=20) for m in ("run", "local")]
    t.run(2.0, until=lambda: all(f.done() for f in futs))
    assert [f.result(0) for f in futs] == [20, 20]


def test_bad_options_are_refused_at_the_caller(team) -> None:
    _, app = team
    with pytest.raises(ValueError, match="on_miss"):
        app.options(deadline=1.0, on_miss="later")
    for bad in (0.0, -1.0, float("inf"), float("nan"), "2"):
        with pytest.raises(ValueError, match="deadline"):
            app.options(deadline=bad)


def test_a_miss_is_counted_in_the_metrics() -> None:
    from prometheus_client import generate_latest

    from ramps.core.events import Submit
    from ramps.runtime.metrics import NodeMetrics

    fake = FakeTeam({"o": (4, 1.0)})
    metrics = NodeMetrics("o", "t")
    for action in fake.handle("o", Submit(program_id="p", program="plan", work=10.0, deadline=1.0,
                                          on_miss="fail")):
        metrics.on_action(action, fake.nodes["o"], now=0.0)
    text = generate_latest(metrics.registry).decode()
    assert 'ramps_deadline_misses_total{program="plan",robot="o"} 1.0' in text
