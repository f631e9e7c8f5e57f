"""Whether a quiet host still lives (``ramps.core.liveness``): a host whose
load reports come seconds apart (``report_rate`` in a large team) or that
sends anything else is suspected when its heartbeats stop, not written off;
one whose reports are overdue is written off. Driven through
``ramps.testing.FakeTeam`` (real nodes, in-memory network)."""

from __future__ import annotations

import pytest

from ramps.core.events import Deliver, Received
from ramps.core.liveness import GAP_DECAY
from ramps.core.loadview import LoadView
from ramps.core.messages import Heartbeat, LinkProbeReply, ProgramRef

from corehelpers import CFG, busy_origin_team, report, submit


def no_beats(sender: str, to: str, msg: object) -> bool:
    return sender == "a" and isinstance(msg, Heartbeat)


def run(team, until: float, *, a_every: float, beats_until: float, step: float = 0.5) -> None:
    """Advance in ``step``s to ``until``: ``a`` reports every ``a_every`` s, ``b`` every step;
    ``a``'s heartbeats are lost from ``beats_until`` on."""
    t = team.now
    while t < until - 1e-9:
        t = round(t + step, 6)
        hold = no_beats if t > beats_until else None
        team.advance(t, hold=hold)
        if abs(t / a_every - round(t / a_every)) < 1e-6:
            team.publish("a")
        team.publish("b")
        team.deliver(hold=hold)


# ---------------------------------------------------------------- the estimate
def test_the_report_gap_follows_the_period_and_leaves_out_outages() -> None:
    view = LoadView("o", cores=1, speed=1.0, max_report_age=10.0)
    seq = iter(range(1, 100))

    def at(t: float, incarnation: int = 0) -> None:
        view.on_report(report("a", seq=next(seq), incarnation=incarnation), t)

    assert view.report_gap("a") == 0.0
    for t in (1.0, 4.0, 7.0, 10.0):
        at(t)
    assert view.report_gap("a") == pytest.approx(3.0)
    # reports on change in between shrink it by a tenth of the time that passes only
    for t in (10.2, 10.4, 10.6):
        at(t)
    assert view.report_gap("a") == pytest.approx(3.0 - 3 * GAP_DECAY * 0.2)
    # a 30 s silence is an outage, not a period; nor is a restart
    at(40.6)
    at(41.0, incarnation=1)
    assert view.report_gap("a") == pytest.approx(3.0 - 3 * GAP_DECAY * 0.2)
    at(42.0, incarnation=1)
    assert view.report_gap("a") == pytest.approx(3.0 - 3 * GAP_DECAY * 0.2 - GAP_DECAY * 1.0)


# ---------------------------------------------------------------- the hedge
def test_a_host_reporting_every_three_seconds_is_suspected_when_its_heartbeats_stop() -> None:
    # a large team's reports come every 3 s: when a's heartbeats stop, its last
    # report is over the heartbeat timeout less a period old, but its next one
    # is not due yet, so a lives as far as anyone knows
    team = busy_origin_team()
    submit(team)
    team.deliver()
    run(team, 12.0, a_every=3.0, beats_until=7.4)
    [failed] = team.notes("failed")
    age = team.nodes["o"].view.report_age("a", team.now)
    assert failed.detail == "heartbeat_timeout" and age is not None
    [suspected] = team.notes("suspected")
    assert suspected.robot == "a"
    assert not team.notes("blacklisted") and not team.nodes["o"].view.is_blacklisted("a")
    assert [n.robot for n in team.notes("placed")] == ["a", "b"]
    team.finish("b", "p", 2, ok=True, value=b"from b")
    assert team.delivered("p") == [Deliver(program_id="p", ok=True, value=b"from b", host="b", attempts=2)]


def test_a_host_whose_reports_are_overdue_is_written_off() -> None:
    # the same silence where a reports every second: its last report is
    # older than its period allows, and the host is written off
    team = busy_origin_team()
    submit(team)
    team.deliver()
    run(team, 7.0, a_every=1.0, beats_until=99.0)
    team.cut.add("a")  # reports and heartbeats stop together
    run(team, 12.0, a_every=1.0, beats_until=99.0)
    assert [n.detail for n in team.notes("failed")] == ["heartbeat_timeout"]
    assert not team.notes("suspected")
    assert team.nodes["o"].view.is_blacklisted("a")


def test_any_message_from_the_host_says_it_lives() -> None:
    # no report from a since the start, its heartbeats lost: a probe reply
    # from it a moment before the timeout says it is alive
    team = busy_origin_team()
    submit(team)
    team.deliver()
    run(team, 3.0, a_every=100.0, beats_until=2.0)
    assert not team.notes("failed")
    team.handle("o", Received(sender="a", msg=LinkProbeReply(sent_at=team.now - 0.01)))
    run(team, 6.0, a_every=100.0, beats_until=2.0)
    [failed] = team.notes("failed")
    assert failed.detail == "heartbeat_timeout"
    assert [n.robot for n in team.notes("suspected")] == ["a"]
    assert not team.nodes["o"].view.is_blacklisted("a")


def test_without_it_the_same_silence_writes_the_host_off() -> None:
    # the case above with nothing heard from a since its acceptance
    team = busy_origin_team()
    submit(team)
    team.deliver()
    run(team, 6.0, a_every=100.0, beats_until=2.0)
    assert [n.detail for n in team.notes("failed")] == ["heartbeat_timeout"]
    assert not team.notes("suspected")
    assert team.nodes["o"].view.is_blacklisted("a")
    assert CFG.hedge_suspects


# ---------------------------------------------------------------- heartbeats read later
def test_a_heartbeat_read_later_counts_from_its_arrival() -> None:
    # a driver that reads a heartbeat at a later round says when it arrived
    # (``Received.at``): the program's silence counts from then, not from the
    # round, so holding heartbeats for a round does not slow failure detection
    def beat(team) -> Heartbeat:
        return Heartbeat(host="a", incarnation=team.nodes["a"].incarnation, programs=[ProgramRef(program_id="p", attempt=1)])

    def silent_until(team, t: float) -> None:
        team.advance(t, hold=no_beats)

    arrived, read = busy_origin_team(), busy_origin_team()
    for team in (arrived, read):
        submit(team)
        team.deliver()
        team.advance(1.0)  # heartbeats until 1.0, then none
        silent_until(team, 2.9)
    arrived.handle("o", Received(sender="a", msg=beat(arrived), at=2.0))  # arrived at 2.0, read at 2.9
    read.handle("o", Received(sender="a", msg=beat(read)))  # the same, heard at 2.9
    assert (arrived.nodes["o"].origin.heard["a"], read.nodes["o"].origin.heard["a"]) == (2.0, 2.9)
    for team in (arrived, read):
        silent_until(team, 2.5 + CFG.heartbeat_timeout)
    assert [n.detail for n in arrived.notes("failed")] == ["heartbeat_timeout"]
    assert not read.notes("failed")
    silent_until(read, 3.0 + CFG.heartbeat_timeout)
    assert [n.detail for n in read.notes("failed")] == ["heartbeat_timeout"]
