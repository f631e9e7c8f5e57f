"""Pure tests of the autonomous program's state machine and the executor,
driven through ``ramps.testing.FakeTeam`` (real nodes, in-memory network)."""

from __future__ import annotations

import random


import pytest

from ramps.core.events import (
    PublishReport,
    Cancel,
    Deliver,
    Note,
    OfferSending,
    PeerAlive,
    PeerLost,
    ProgramFinished,
    Received,
    Send,
    StartProgram,
    StopProgram,
    Submit,
)
from ramps.core.messages import (
    CancelProgram,
    Heartbeat,
    OffloadAccepted,
    OffloadRejected,
    OffloadRequest,
    ProgramRef,
    ProgramResult,
    ResultAck,
    WireError,
    decode,
    encode,
)
from ramps.core.node import Node
from ramps.core.origin import Origin, resolve_handlers
from ramps.core.program import (
    TRANSITIONS,
    AutonomousProgram,
    Event,
    IllegalTransition,
    Outcome,
    ProgramState,
    ProtocolError,
    Transition,
)

from ramps.core.config import RampsConfig
from corehelpers import CFG, Team, busy_origin_team, report, submit


# =================================================================== state machine: happy path
def test_happy_path_remote() -> None:
    team = busy_origin_team()
    submit(team, args=b"params", result_size=10)
    [req] = team.sent(OffloadRequest, to="a")
    assert (req.program_id, req.attempt, req.origin, req.args, req.force) == ("p", 1, "o", b"params", False)
    assert team.program("p").state is ProgramState.OFFERED
    team.deliver()
    [start] = team.actions(StartProgram, "a")
    assert (start.program_id, start.attempt, start.origin, start.args) == ("p", 1, "o", b"params")
    assert team.program("p").state is ProgramState.RUNNING
    team.advance(6.0)  # heartbeats keep it alive well past heartbeat_timeout
    assert team.sent(Heartbeat, to="o")
    assert team.program("p").state is ProgramState.RUNNING
    assert not team.notes("failed")
    team.finish("a", "p", 1, ok=True, value=b"route")
    assert team.delivered("p") == [Deliver(program_id="p", ok=True, value=b"route", host="a", attempts=1)]
    assert team.program("p").state is ProgramState.DONE
    assert team.sent(ResultAck, to="a")
    assert team.nodes["a"].executor.unacked_results() == 0
    stats = team.nodes["o"].statistics()
    assert (stats.placements, stats.delivered, stats.anomalies, stats.host_failures) == (1, 1, 0, 0)
    assert stats.active_programs == 0
    # nothing left but the periodic link probe
    assert team.nodes["o"].next_deadline() == team.nodes["o"]._probe_due
    assert team.nodes["o"].origin.next_deadline() is None
    team.advance(9.0)
    assert team.nodes["a"].executor.next_deadline() is None  # nothing left to resend or report


def test_local_placement_runs_through_the_same_protocol() -> None:
    team = Team({"o": (4, 1.0), "a": (4, 1.0)})
    team.publish()
    submit(team)
    # placed, requested, accepted and started without a single message leaving o
    assert [n.robot for n in team.notes("placed")] == ["o"]
    assert not team.inflight
    [start] = team.actions(StartProgram, "o")
    assert team.program("p").state is ProgramState.RUNNING
    team.finish("o", "p", start.attempt, ok=True, value=b"v")
    assert team.delivered("p") == [Deliver(program_id="p", ok=True, value=b"v", host="o", attempts=1)]
    assert team.nodes["o"].executor.unacked_results() == 0


# =================================================================== host failures
def test_connect_timeout_blacklists_backs_off_and_replaces_elsewhere() -> None:
    team = busy_origin_team()
    submit(team)
    team.deliver(hold=lambda s, to, m: isinstance(m, OffloadRequest))  # a slow link to a
    assert [n.robot for n in team.notes("placed")] == ["a"]
    team.advance(CFG.connect_timeout - 0.01)
    assert not team.notes("failed")
    team.advance(CFG.connect_timeout)
    [failed] = team.notes("failed")
    assert (failed.robot, failed.detail) == ("a", "connect_timeout")
    assert [n.robot for n in team.notes("blacklisted")] == ["a"]
    assert team.nodes["o"].view.is_blacklisted("a")
    assert team.sent(CancelProgram, to="a") == [CancelProgram(program_id="p", attempt=1, origin="o")]
    [backoff] = team.notes("backoff")
    assert 0.0 <= float(backoff.detail) <= CFG.backoff_max
    assert team.program("p").state is ProgramState.BACKOFF
    wake = team.nodes["o"].next_deadline()
    assert wake == pytest.approx(CFG.connect_timeout + float(backoff.detail), abs=1e-3)
    team.advance(wake)
    placed = team.notes("placed")
    assert [(n.robot, n.attempt) for n in placed] == [("a", 1), ("b", 2)]
    assert team.program("p").state is ProgramState.RUNNING  # b accepted at once
    # the first request finally reaches a; its acceptance makes o stop that copy
    cancels_before = len(team.sent(CancelProgram, to="a"))
    team.release()
    assert team.sent(OffloadAccepted, by="a") == [OffloadAccepted(program_id="p", attempt=1, host="a", accept_seq=1)]
    cancels = team.sent(CancelProgram, by="o", to="a")
    assert len(cancels) == cancels_before + 1 and cancels[-1].attempt == 1
    assert team.actions(StopProgram, "a") == [StopProgram(program_id="p", attempt=1)]
    assert not team.nodes["a"].executor.running
    team.finish("b", "p", 2, ok=True, value=b"from b")
    assert team.delivered("p") == [Deliver(program_id="p", ok=True, value=b"from b", host="b", attempts=2)]


def test_heartbeat_timeout_writes_the_host_off() -> None:
    team = busy_origin_team()
    submit(team)
    team.deliver()
    team.advance(1.0)
    last_beat = max(t for t, r, a in team.log if r == "a" and isinstance(a, Send) and isinstance(a.msg, Heartbeat))
    team.cut.add("a")  # a keeps computing, but nobody hears it
    team.advance(last_beat + CFG.heartbeat_timeout - 0.01)
    assert not team.notes("failed")
    team.advance(last_beat + CFG.heartbeat_timeout + 0.01)
    [failed] = team.notes("failed")
    assert (failed.robot, failed.detail) == ("a", "heartbeat_timeout")
    assert team.nodes["o"].view.is_blacklisted("a")
    assert team.program("p").state is ProgramState.BACKOFF
    team.advance(team.now + CFG.backoff_max)
    assert [(n.robot, n.attempt) for n in team.notes("placed")] == [("a", 1), ("b", 2)]
    # a comes back and publishes: the blacklisting is lifted
    team.cut.discard("a")
    team.publish("a")
    assert team.notes("unblacklisted") and not team.nodes["o"].view.is_blacklisted("a")


def test_peer_lost_writes_the_host_off_at_once() -> None:
    team = busy_origin_team()
    submit(team)
    team.deliver()
    assert team.handle("o", PeerLost(robot="b")) == []  # nothing of ours there
    # b back: nothing to place, and it hears o's load at once, not a period later
    [report] = team.handle("o", PeerAlive(robot="b"))
    assert isinstance(report, PublishReport) and report.report.robot == "o"
    team.cut.add("a")
    team.now = 0.3
    team.handle("o", PeerLost(robot="a"))
    [failed] = team.notes("failed")
    assert (failed.robot, failed.detail) == ("a", "host_lost")
    assert team.nodes["o"].view.is_blacklisted("a")
    assert team.program("p").state is ProgramState.BACKOFF
    # the host's session is gone for certain: a short jitter, not the
    # paper's back-off of up to backoff_max
    [wait] = [float(n.detail) for n in team.notes("backoff")]
    assert 0.0 <= wait <= CFG.backoff_lost_max < CFG.backoff_max
    team.advance(0.3 + CFG.backoff_lost_max)
    assert [n.robot for n in team.notes("placed")] == ["a", "b"]


def test_silent_host_keeps_the_papers_backoff() -> None:
    # a heartbeat timeout is not certain death (a lost message, a frozen
    # host): the randomised back-off that keeps origins from herding stays
    team = busy_origin_team()
    for i in range(20):
        submit(team, pid=f"p{i}")
    team.deliver()
    team.cut.update({"a", "b"})
    team.advance(CFG.heartbeat_timeout + 1.0)
    waits = [float(n.detail) for n in team.notes("backoff")]
    assert len(waits) == 20 and max(waits) > CFG.backoff_lost_max and max(waits) <= CFG.backoff_max


def test_a_stalled_node_keeps_its_own_programs() -> None:
    # issue 14: a node whose driver stalls (busy robot, GC pause, SIGSTOP)
    # used to check heartbeat timeouts before sending its own programs'
    # heartbeats, and wrote its own programs off
    n = Node("r1", cores=4, speed=1.0, rng=random.Random(0))
    acts = n.handle(Submit(program_id="p", program="x", work=50.0), 0.0)
    assert any(isinstance(a, StartProgram) for a in acts)
    t = 0.0
    for _ in range(4):
        t += 0.5
        n.tick(t)
    for stall in (2.5, 5.0):
        t += stall
        acts = n.tick(t)
        assert not [a for a in acts if isinstance(a, StopProgram)]
        assert not [a for a in acts if isinstance(a, Note) and a.what in ("failed", "backoff")]
    assert n.origin.programs["p"].state is ProgramState.RUNNING and n.origin.programs["p"].attempt == 1


def test_isolated_origin_runs_the_program_itself_and_keeps_the_remote_copy_wanted() -> None:
    team = busy_origin_team()
    submit(team)
    team.deliver()
    team.advance(CFG.isolation_timeout + 1.0)  # heartbeats flow, but no load reports any more
    team.cut.update({"a", "b"})  # now o is cut off from everybody
    team.advance(team.now + CFG.heartbeat_timeout + 0.1)
    [isolated] = team.notes("isolated")
    assert isolated.robot == "a"
    assert not team.notes("blacklisted")
    assert [n.robot for n in team.notes("placed")] == ["a", "o"]
    # the link heals; a's result (attempt 1) arrives first and wins
    team.cut.clear()
    team.finish("a", "p", 1, ok=True, value=b"remote")
    assert team.delivered("p") == [Deliver(program_id="p", ok=True, value=b"remote", host="a", attempts=2)]
    assert not team.nodes["o"].executor.running  # the local copy was stopped


def test_origin_cut_off_revives_the_copy_it_wrote_off_a_moment_before() -> None:
    # a cut origin loses its teammates one lease at a time: the first loss
    # looks like a host failure; once every teammate is gone, it is clear the
    # origin was the one cut off, so the written-off copy is wanted again
    team = busy_origin_team()
    submit(team)
    team.deliver()
    team.cut.add("o")
    team.handle("o", PeerLost(robot="a"))
    [failed] = team.notes("failed")
    assert (failed.robot, failed.detail) == ("a", "host_lost")
    assert team.notes("blacklisted") and not team.notes("isolated")
    team.handle("o", PeerLost(robot="b"))
    [revived] = team.notes("isolated")
    assert (revived.robot, revived.attempt) == ("a", 1)
    team.advance(team.now + CFG.backoff_max + 0.1)
    assert [n.robot for n in team.notes("placed")] == ["a", "o"]  # runs here meanwhile
    # the link heals; a's copy finishes first and is the one delivered, once
    team.cut.clear()
    team.finish("a", "p", 1, ok=True, value=b"remote")
    assert team.delivered("p") == [Deliver(program_id="p", ok=True, value=b"remote", host="a", attempts=2)]
    assert not team.nodes["o"].executor.running
    assert team.nodes["o"].origin.discarded == 0


def test_origin_cut_off_without_liveliness_revives_once_all_teammates_fall_silent() -> None:
    # no liveliness at all: the host's heartbeats time out first; silence
    # from every teammate for isolation_timeout then shows who was cut off
    team = busy_origin_team()
    submit(team)
    team.deliver()
    team.cut.add("o")
    team.advance(team.now + CFG.heartbeat_timeout + 0.1)
    assert [n.detail for n in team.notes("failed")] == ["heartbeat_timeout"]
    assert not team.notes("isolated")
    deadline = team.nodes["o"].next_deadline()
    assert deadline is not None
    team.advance(CFG.isolation_timeout + 1.0)
    [revived] = [n for n in team.notes("isolated") if n.robot == "a"]
    assert revived.attempt == 1 and revived.detail.startswith("revived")
    team.cut.clear()
    team.finish("a", "p", 1, ok=True, value=b"remote")
    assert [d.host for d in team.delivered("p")] == ["a"]


@pytest.mark.parametrize("late_results", [True, False])
def test_a_host_written_off_while_others_stay_is_not_revived(late_results: bool) -> None:
    team = busy_origin_team(config=RampsConfig(late_results=late_results))
    submit(team)
    team.deliver()
    team.handle("o", PeerLost(robot="a"))
    team.advance(team.now + CFG.backoff_max + 0.1)
    assert not team.notes("isolated")
    team.handle("o", Received(sender="a", msg=ProgramResult(program_id="p", attempt=1, host="a", ok=True)))
    if late_results:  # the written-off copy's result is the program's: delivered once
        assert [d.host for d in team.delivered("p")] == ["a"] and team.nodes["o"].origin.discarded == 0
    else:  # the paper's: discarded
        assert not team.delivered("p") and team.nodes["o"].origin.discarded == 1


def test_a_host_that_still_publishes_is_suspected_not_written_off() -> None:
    # heartbeats about the program are lost, but the host keeps publishing
    # its load: keep its copy wanted, run the program elsewhere too
    team = busy_origin_team()
    submit(team)
    team.deliver()
    no_beats = lambda s, to, m: isinstance(m, Heartbeat)  # noqa: E731
    t = team.now
    while t < CFG.heartbeat_timeout + 1.0:
        t += 0.5
        team.advance(t, hold=no_beats)
        team.publish("a", "b")
        team.deliver(hold=no_beats)
    [suspected] = team.notes("suspected")
    assert (suspected.robot, suspected.detail.split(",")[0]) == ("a", "heartbeat_timeout")
    assert not team.notes("blacklisted") and not team.nodes["o"].view.is_blacklisted("a")
    assert [n.robot for n in team.notes("placed")] == ["a", "b"]
    # a's copy finishes first: it is the one delivered, once, and b's copy stops
    team.finish("a", "p", 1, ok=True, value=b"from a")
    assert team.delivered("p") == [Deliver(program_id="p", ok=True, value=b"from a", host="a", attempts=2)]
    assert not team.nodes["b"].executor.running


def test_a_host_cut_off_right_after_a_report_is_written_off_not_suspected() -> None:
    # reports and heartbeats stop together: the last report is older than the
    # silence, so the host is written off as usual
    team = busy_origin_team()
    submit(team)
    team.deliver()
    t = team.now
    while t < 3.0:
        t += 0.5
        team.advance(t)
        team.publish("a", "b")
        team.deliver()
    team.cut.add("a")
    while t < 3.0 + CFG.heartbeat_timeout + 0.6:
        t += 0.5
        team.advance(t)
        team.publish("b")
        team.deliver()
    assert not team.notes("suspected")
    assert team.nodes["o"].view.is_blacklisted("a")


def test_the_paper_policy_writes_off_a_silent_host_even_if_it_publishes() -> None:
    team = busy_origin_team(config=RampsConfig.paper())
    submit(team)
    team.deliver()
    no_beats = lambda s, to, m: isinstance(m, Heartbeat)  # noqa: E731
    t = team.now
    while t < RampsConfig.paper().heartbeat_timeout + 1.5:
        t += 0.5
        team.advance(t, hold=no_beats)
        team.publish("a", "b")
        team.deliver(hold=no_beats)
    assert not team.notes("suspected") and team.notes("blacklisted")


def test_an_offer_still_being_sent_whole_is_not_timed_out_until_its_last_byte_is_out() -> None:
    """A large offer goes out on a thread of its own (``OfferSending``): the
    host cannot accept it before it is through, however stale the origin's
    estimate of the link, so the connect timeout counts from then."""
    team = busy_origin_team()
    submit(team)
    team.deliver(hold=lambda s, to, m: isinstance(m, OffloadRequest))
    [placed] = team.notes("placed")
    team.handle("o", OfferSending(program_id="p", attempt=1))
    team.advance(3 * CFG.connect_timeout)  # a slow link: still sending
    assert not team.notes("failed")
    assert team.program("p").state is ProgramState.OFFERED
    sent_at = team.now
    team.handle("o", OfferSending(program_id="p", attempt=1, done=True))
    team.advance(sent_at + CFG.connect_timeout - 0.01)
    assert not team.notes("failed")  # the host has connect_timeout from the last byte
    team.advance(sent_at + CFG.connect_timeout + 0.01)
    [failed] = team.notes("failed")
    assert (failed.robot, failed.detail) == (placed.robot, "connect_timeout")
    # the attempt's word from an earlier one changes nothing (an old attempt's thread)
    team.handle("o", OfferSending(program_id="p", attempt=1, done=True))
    assert team.program("p").sending == 0


def test_an_offer_sent_whole_and_accepted_runs_as_any_other() -> None:
    team = busy_origin_team()
    submit(team)
    team.deliver(hold=lambda s, to, m: isinstance(m, OffloadRequest))
    team.handle("o", OfferSending(program_id="p", attempt=1))
    team.advance(2 * CFG.connect_timeout)
    team.handle("o", OfferSending(program_id="p", attempt=1, done=True))
    team.release()  # the offer arrives now
    assert team.program("p").state is ProgramState.RUNNING
    team.advance(team.now + 3 * CFG.connect_timeout)
    assert not team.notes("failed")


def _in_backoff_after_connect_timeout() -> Team:
    team = busy_origin_team()
    submit(team)
    team.deliver(hold=lambda s, to, m: to == "a")
    team.advance(CFG.connect_timeout)
    assert team.program("p").state is ProgramState.BACKOFF
    team.held.clear()
    return team


def test_late_acceptance_during_backoff_cancels_the_stray_copy() -> None:
    # the written-off attempt is no longer current: its late acceptance is stale
    team = _in_backoff_after_connect_timeout()
    cancels = len(team.sent(CancelProgram, to="a"))
    team.handle("o", Received(sender="a", msg=OffloadAccepted(program_id="p", attempt=1, host="a", accept_seq=1)))
    assert len(team.sent(CancelProgram, to="a")) == cancels + 1
    assert team.nodes["o"].statistics().anomalies == 0


def test_late_result_during_backoff_is_acknowledged_and_discarded() -> None:
    team = _in_backoff_after_connect_timeout()
    team.handle("o", Received(sender="a", msg=ProgramResult(program_id="p", attempt=1, host="a", ok=True)))
    assert team.sent(ResultAck, to="a") == [ResultAck(program_id="p", attempt=1, origin="o")]
    assert team.nodes["o"].statistics().anomalies == 0
    assert not team.delivered("p")


# =================================================================== rejections
def test_busy_rejection_replaces_at_once_without_backoff() -> None:
    team = busy_origin_team()
    # load o's view does not show yet, enough that b (idle, half a's speed) is now better
    team.nodes["a"].executor.background = 12.0
    submit(team)
    team.deliver()
    [rej] = team.sent(OffloadRejected, by="a")
    assert (rej.reason, rej.permanent) == ("busy", False)
    assert rej.report is not None and rej.report.runnable == 12.0
    assert [(n.robot, n.attempt) for n in team.notes("placed")] == [("a", 1), ("b", 2)]
    assert not team.notes("backoff") and not team.notes("blacklisted")
    assert team.nodes["o"].view.report_of("a").runnable == 12.0  # the fresh report was taken in
    assert team.program("p").state is ProgramState.RUNNING
    assert team.nodes["o"].statistics().rejections == 1
    assert team.nodes["a"].statistics().refused == 1


def test_busier_host_still_better_than_the_alternative_takes_the_program() -> None:
    # a has 6 tasks o does not know of: the program gets 4/7 of a 2.0 core
    # there (44 s), still sooner than on idle b (50 s): eq. (1) holds at the host
    team = busy_origin_team()
    team.nodes["a"].executor.background = 6.0
    submit(team)
    [req] = team.sent(OffloadRequest, to="a")
    assert req.time_budget == 50.0  # b's computation; both pay the same link
    team.deliver()
    assert not team.sent(OffloadRejected, by="a")
    assert [(n.robot, n.attempt) for n in team.notes("placed")] == [("a", 1)]
    assert team.program("p").state is ProgramState.RUNNING


def test_rejections_teach_the_origin_each_hosts_true_load() -> None:
    hosts = ["a", "b", "c", "d"]
    team = Team({"o": (1, 1.0), **{h: (4, 1.0) for h in hosts}})
    team.nodes["o"].executor.background = 10.0
    team.publish()
    for h in hosts:
        team.nodes[h].executor.background = 9.0  # all busier than o thinks
    submit(team)
    team.deliver()
    team.advance(5.0)
    requests = team.sent(OffloadRequest, by="o")
    # each rejection carried the host's true load; once the last unknown host
    # was known to be no worse than the others, the program stayed there
    assert len(requests) == len(hosts) and not any(r.force for r in requests)
    assert {r.host for r in requests} == set(hosts)
    assert len(team.sent(OffloadRejected, by=None)) == len(hosts) - 1
    assert team.actions(StartProgram, requests[-1].host)
    assert team.program("p").state is ProgramState.RUNNING
    # after the second rejection in a row, short random waits (contention)
    waits = [n.detail for n in team.notes("backoff")]
    assert len(waits) == 2 and all("rejections" in w for w in waits)
    assert not team.notes("blacklisted")


def test_after_max_rejections_the_request_is_forced() -> None:
    hosts = ["a", "b", "c", "d"]
    team = Team({"o": (1, 1.0), **{h: (4, 1.0) for h in hosts}}, config=RampsConfig(max_rejections=2))
    team.nodes["o"].executor.background = 10.0
    team.publish()
    for h in hosts:
        team.nodes[h].executor.background = 9.0
    submit(team)
    team.deliver()
    team.advance(5.0)
    requests = team.sent(OffloadRequest, by="o")
    assert [r.force for r in requests] == [False, False, True]
    forced = requests[-1]
    assert team.actions(StartProgram, forced.host)  # taken regardless of load
    assert team.program("p").state is ProgramState.RUNNING
    assert not team.notes("blacklisted")


def test_permanent_rejection_delivers_a_clear_error() -> None:
    team = busy_origin_team(registry={"a": frozenset({"route_plan"}), "b": frozenset({"route_plan"})})
    submit(team, program="teleport")
    team.deliver()
    [rej] = team.sent(OffloadRejected, by="a")
    assert (rej.reason, rej.permanent) == ("unknown_program", True)
    [d] = team.delivered("p")
    assert d.ok is False and d.host == "a"
    assert "'teleport'" in d.error and "unknown_program" in d.error and "a refused" in d.error
    assert len(team.notes("placed")) == 1  # not tried elsewhere
    assert team.program("p").state is ProgramState.FAILED
    assert not team.nodes["o"].view.is_blacklisted("a")


def test_request_for_another_host_is_a_bad_request() -> None:
    a = Node("a", cores=1, speed=1.0, rng=random.Random(0))
    req = OffloadRequest(program_id="p", attempt=1, origin="o", host="z", program="x")
    [note, send] = a.handle(Received(sender="o", msg=req), 0.0)
    assert note.what == "refused"
    assert send.to == "o" and send.msg.reason == "bad_request" and send.msg.permanent


# =================================================================== results
def test_retryable_worker_loss_is_placed_again() -> None:
    team = busy_origin_team()
    submit(team)
    team.deliver()
    team.finish("a", "p", 1, ok=False, error="killed: out of memory", retryable=True)
    assert not team.delivered("p")
    [failed] = team.notes("failed")
    assert failed.robot == "a" and "worker lost" in failed.detail
    assert not team.nodes["o"].view.is_blacklisted("a")  # the robot is fine
    assert team.sent(ResultAck, to="a")
    # not a host failure: no back-off, placed again at once, on another robot
    assert not team.notes("backoff")
    [_, second] = team.notes("placed")
    assert second.attempt == 2 and second.robot != "a"
    team.finish(second.robot, "p", 2, ok=True, value=b"ok")
    assert team.delivered("p") == [Deliver(program_id="p", ok=True, value=b"ok", host=second.robot, attempts=2)]


def test_program_error_is_delivered_not_retried() -> None:
    team = busy_origin_team()
    submit(team)
    team.deliver()
    team.finish("a", "p", 1, ok=False, error="ValueError: no route")
    assert team.delivered("p") == [Deliver(program_id="p", ok=False, error="ValueError: no route", error_kind="program", host="a",
                                           attempts=1)]


def test_duplicate_result_delivered_once_and_acknowledged() -> None:
    team = busy_origin_team()
    submit(team)
    team.deliver()
    team.handle("a", ProgramFinished(program_id="p", attempt=1, ok=True, value=b"v"))
    team.deliver(hold=lambda s, to, m: isinstance(m, ResultAck))  # the first ack is lost
    team.held.clear()
    assert len(team.delivered("p")) == 1
    team.advance(team.now + CFG.result_resend + CFG.heartbeat_period + 0.01)  # a resends
    assert len(team.sent(ProgramResult, by="a")) == 2
    assert len(team.delivered("p")) == 1
    assert len(team.sent(ResultAck, by="o")) == 2  # the copy is acknowledged too
    assert [n.what for n in team.notes("discarded")] == ["discarded"]
    assert team.nodes["o"].statistics().discarded == 1
    assert team.nodes["a"].executor.unacked_results() == 0


def test_result_for_unknown_program_is_an_anomaly_not_a_crash() -> None:
    o = Node("o", cores=1, speed=1.0, rng=random.Random(0))
    actions = o.handle(Received(sender="a", msg=ProgramResult(program_id="ghost", attempt=3, host="a", ok=True)), 1.0)
    assert [a.what for a in actions if isinstance(a, Note)] == ["anomaly"]
    # acknowledged all the same, so the host stops resending
    assert [a for a in actions if isinstance(a, Send)] == [
        Send(to="a", msg=ResultAck(program_id="ghost", attempt=3, origin="o"))]
    assert not [a for a in actions if isinstance(a, Deliver)]
    o.handle(Received(sender="a", msg=OffloadAccepted(program_id="ghost", attempt=1, host="a", accept_seq=1)), 1.0)
    o.handle(Received(sender="a", msg=Heartbeat(host="a", incarnation=0, programs=[ProgramRef("ghost", 1)])), 1.0)
    assert o.statistics().anomalies == 3


def test_illegal_transition_from_a_peer_is_counted_not_raised() -> None:
    team = busy_origin_team()
    submit(team)
    team.deliver()
    assert team.program("p").state is ProgramState.RUNNING
    # a rejection of a program a already accepted: no transition from running
    team.handle("o", Received(sender="a", msg=OffloadRejected(program_id="p", attempt=1, host="a", reason="busy",
                                                              permanent=False)))
    [anomaly] = team.notes("anomaly")
    assert "'running'" in anomaly.detail and "'rejected'" in anomaly.detail
    assert team.program("p").state is ProgramState.RUNNING


# =================================================================== cancel
def test_cancel_by_the_application() -> None:
    team = busy_origin_team()
    submit(team)
    team.deliver()
    team.handle("o", Cancel(program_id="p"))
    [d] = team.delivered("p")
    assert d.ok is False and "cancelled" in d.error
    team.deliver()
    assert team.actions(StopProgram, "a") == [StopProgram(program_id="p", attempt=1)]
    team.handle("o", Cancel(program_id="p"))  # again: nothing more
    assert len(team.delivered("p")) == 1
    with pytest.raises(KeyError, match="nope"):
        team.handle("o", Cancel(program_id="nope"))


def test_cancel_during_backoff() -> None:
    team = busy_origin_team()
    submit(team)
    team.handle("o", PeerLost(robot="a"))
    assert team.program("p").state is ProgramState.BACKOFF
    team.handle("o", Cancel(program_id="p"))
    assert team.delivered("p")[0].error == "cancelled by the application"
    team.advance(10.0)
    assert len(team.notes("placed")) == 1  # the back-off timer died with it


def test_duplicate_submit_is_local_misuse() -> None:
    team = busy_origin_team()
    submit(team)
    with pytest.raises(ValueError, match="already submitted"):
        submit(team)


# =================================================================== executor
def _request(**kw) -> OffloadRequest:
    fields = dict(program_id="p", attempt=1, origin="o", host="a", program="route_plan", work=5.0)
    fields.update(kw)
    return OffloadRequest(**fields)


def test_executor_resends_unacknowledged_result_until_acknowledged() -> None:
    a = Node("a", cores=1, speed=1.0, rng=random.Random(0))
    a.handle(Received(sender="o", msg=_request()), 0.0)
    [send] = [x for x in a.handle(ProgramFinished(program_id="p", attempt=1, ok=True, value=b"v"), 1.0)
              if isinstance(x, Send)]
    first = send.msg
    resent: list[float] = []
    now = 1.0
    while (d := a.next_deadline()) is not None and d <= 4.2:
        now = d
        resent += [now for x in a.tick(now) if isinstance(x, Send) and x.msg == first]
    assert len(resent) == 3
    assert all(b - a_ >= CFG.result_resend - 1e-9 for a_, b in zip([1.0] + resent, resent))
    assert a.executor.unacked_results() == 1
    a.handle(Received(sender="o", msg=ResultAck(program_id="p", attempt=1, origin="o")), now)
    assert a.executor.unacked_results() == 0
    for _ in range(5):
        d = a.executor.next_deadline()
        if d is None:
            break
        assert not [x for x in a.tick(d) if isinstance(x, Send)]
    assert a.executor.next_deadline() is None


def test_executor_ignores_an_ack_from_somebody_else() -> None:
    a = Node("a", cores=1, speed=1.0, rng=random.Random(0))
    a.handle(Received(sender="o", msg=_request()), 0.0)
    a.handle(ProgramFinished(program_id="p", attempt=1, ok=True), 1.0)
    a.handle(Received(sender="x", msg=ResultAck(program_id="p", attempt=1, origin="x")), 1.0)
    assert a.executor.unacked_results() == 1


def test_executor_is_idempotent_on_a_repeated_request() -> None:
    a = Node("a", cores=1, speed=1.0, rng=random.Random(0))
    first = a.handle(Received(sender="o", msg=_request()), 0.0)
    again = a.handle(Received(sender="o", msg=_request()), 0.1)
    assert sum(isinstance(x, StartProgram) for x in first + again) == 1
    accepts = [x.msg for x in first + again if isinstance(x, Send)]
    assert accepts == [OffloadAccepted(program_id="p", attempt=1, host="a", accept_seq=1)] * 2
    assert a.executor.accepted_total == 1 and len(a.executor.running) == 1
    a.handle(ProgramFinished(program_id="p", attempt=1, ok=True), 1.0)
    late = a.handle(Received(sender="o", msg=_request()), 1.1)  # result not yet acknowledged
    assert not [x for x in late if isinstance(x, StartProgram)]
    assert a.executor.accepted_total == 1


def test_executor_heartbeats_list_programs_per_origin() -> None:
    a = Node("a", cores=4, speed=1.0, incarnation=7, rng=random.Random(0))
    a.handle(Received(sender="o", msg=_request(program_id="p1")), 0.0)
    a.handle(Received(sender="o", msg=_request(program_id="p2")), 0.0)
    a.handle(Received(sender="q", msg=_request(program_id="q1", origin="q")), 0.0)
    beats = {x.to: x.msg for x in a.tick(a.executor.next_deadline()) if isinstance(x, Send)}
    assert beats == {
        "o": Heartbeat(host="a", incarnation=7, programs=[ProgramRef("p1", 1), ProgramRef("p2", 1)]),
        "q": Heartbeat(host="a", incarnation=7, programs=[ProgramRef("q1", 1)]),
    }


def test_executor_cancel_stops_only_the_origins_own_program() -> None:
    a = Node("a", cores=4, speed=1.0, rng=random.Random(0))
    a.handle(Received(sender="o", msg=_request()), 0.0)
    assert a.handle(Received(sender="x", msg=CancelProgram(program_id="p", attempt=1, origin="x")), 0.1) == []
    stopped = a.handle(Received(sender="o", msg=CancelProgram(program_id="p", attempt=1, origin="o")), 0.2)
    assert stopped[0] == StopProgram(program_id="p", attempt=1)
    assert [type(x) for x in stopped[1:]] == [PublishReport]  # the team hears at once that a is idle again
    assert stopped[1].report.ramps_running == 0
    assert not a.executor.running
    assert a.handle(ProgramFinished(program_id="p", attempt=1, ok=True), 0.5) == []  # nobody wants it


# =================================================================== the transition table
def test_missing_transition_names_program_state_and_event() -> None:
    ap = AutonomousProgram(Submit(program_id="prog-42", program="x"), 0.0)
    with pytest.raises(ProtocolError) as info:
        ap.transition("teleported")
    err = info.value
    assert (err.program_id, err.state, err.event) == ("prog-42", ProgramState.OFFERED, "teleported")
    assert "prog-42" in str(err) and "'offered'" in str(err) and "'teleported'" in str(err)
    ap.state = ProgramState.DONE
    with pytest.raises(ProtocolError, match="prog-42.*'done'.*'result'"):
        ap.transition(Event.RESULT)
    ap.state = ProgramState.RUNNING
    assert ap.transition("heartbeat") is TRANSITIONS[ProgramState.RUNNING][Event.HEARTBEAT]


def test_transition_table_is_complete_and_every_handler_exists() -> None:
    assert set(TRANSITIONS) == set(ProgramState)
    handlers = resolve_handlers(Origin, TRANSITIONS)
    for state, row in TRANSITIONS.items():
        for event, transition in row.items():
            assert isinstance(event, Event)
            assert handlers[transition.handler] is getattr(Origin, "_" + transition.handler)
            assert transition.outcomes, (state, event)
            assert all(o.state is None or isinstance(o.state, ProgramState) for o in transition.outcomes)
    live = set(ProgramState) - {ProgramState.DONE, ProgramState.FAILED}
    for state in live:
        assert TRANSITIONS[state][Event.CANCEL].allowed(state) == {ProgramState.FAILED}, state
    assert TRANSITIONS[ProgramState.DONE] == {} and TRANSITIONS[ProgramState.FAILED] == {}
    # every event is handled somewhere, and "stays" means the state it came from
    assert {e for row in TRANSITIONS.values() for e in row} == set(Event)
    assert TRANSITIONS[ProgramState.RUNNING][Event.ACCEPTED].allowed(ProgramState.RUNNING) == {ProgramState.RUNNING}


def test_a_misspelt_handler_fails_when_the_table_is_resolved() -> None:
    table = {ProgramState.RUNNING: {Event.HEARTBEAT: Transition("on_heartbeet", (Outcome(None),))}}
    with pytest.raises(TypeError, match="'running'.*'heartbeat'.*'on_heartbeet'.*_on_heartbeet"):
        resolve_handlers(Origin, table)


def test_a_handler_leaving_the_program_outside_its_allowed_states_raises(monkeypatch) -> None:
    team = Team({"o": (4, 1.0), "a": (4, 1.0)})
    team.publish()
    submit(team)
    team.deliver()
    assert team.program("p").state is ProgramState.RUNNING
    # pretend the table said a heartbeat sends a running program to back-off:
    # the real handler keeps it running, which the origin must refuse
    wrong = Transition("on_heartbeat", (Outcome(ProgramState.BACKOFF, "never"),))
    monkeypatch.setitem(TRANSITIONS[ProgramState.RUNNING], Event.HEARTBEAT, wrong)
    origin = team.nodes["o"].origin
    with pytest.raises(IllegalTransition) as info:
        origin._step(team.program("p"), Event.HEARTBEAT, 1.0, [], None)
    err = info.value
    assert (err.program_id, err.state, err.event, err.handler, err.got, err.allowed) == (
        "p", ProgramState.RUNNING, Event.HEARTBEAT, "on_heartbeat", ProgramState.RUNNING,
        frozenset({ProgramState.BACKOFF}))
    assert str(err) == ("program p: handler 'on_heartbeat' for event 'heartbeat' in state 'running' "
                        "left it 'running'; allowed: backoff")


def test_an_event_a_peer_sent_in_the_wrong_state_is_an_anomaly_not_a_raise() -> None:
    team = Team({"o": (4, 1.0), "a": (4, 1.0)})
    team.publish()
    submit(team)
    team.deliver()
    ap = team.program("p")
    ap.state = ProgramState.BACKOFF  # as if backing off when a stray acceptance arrives
    out: list = []
    team.nodes["o"].origin._step(ap, Event.ACCEPTED, 2.0, out, None)
    assert [a.what for a in out if isinstance(a, Note)] == ["anomaly"]
    assert "'backoff'" in out[0].detail and "'accepted'" in out[0].detail
    with pytest.raises(ProtocolError):  # the application's own cancel of a finished program is misuse
        ap.state = ProgramState.DONE
        team.nodes["o"].origin._step(ap, Event.CANCEL, 2.0, out, None)


# =================================================================== bugs found by review, now fixed
@pytest.mark.parametrize("policy, bad", [
    ("ramps", {"cores": 0}),
    ("ramps", {"speed": 0.0}),
    ("paper", {"cores": 0}),
])
def test_bad_load_report_from_a_peer_never_crashes_the_origin(policy: str, bad: dict) -> None:
    node = Node("o", cores=1, speed=1.0, policy=policy, rng=random.Random(0))
    try:
        env = decode(encode("a", report("a", **bad)))
    except WireError:
        return  # refused at the boundary: fine
    node.handle(Received(sender="a", msg=env.msg), 0.0)
    node.handle(Submit(program_id="p", program="x"), 0.1)  # must not raise


def test_blacklist_lifted_by_a_rejection_report_is_noted() -> None:
    team = busy_origin_team()
    submit(team, "p1")
    team.deliver()
    team.cut.add("a")
    team.now = 1.0
    submit(team, "p2")  # offered to a too, still waiting
    team.advance(CFG.heartbeat_timeout + 0.6)  # p1 writes a off
    assert team.nodes["o"].view.is_blacklisted("a")
    team.cut.discard("a")
    a = team.nodes["a"]
    a.make_report(cpu_busy=4.0, runnable=7.0, ramps_avg=1.0, window=1.0)  # published; o missed it
    fresh = a.current_report()
    team.handle("o", Received(sender="a", msg=OffloadRejected(
        program_id="p2", attempt=1, host="a", reason="busy", permanent=False, report=fresh)))
    assert not team.nodes["o"].view.is_blacklisted("a")  # lifted, by the rules
    assert [n.robot for n in team.notes("unblacklisted")] == ["a"]


# =================================================================== randomness is injected
def test_a_node_needs_its_random_generator() -> None:
    with pytest.raises(TypeError, match="rng"):
        Node("a", cores=1, speed=1.0)  # type: ignore[call-arg]
    with pytest.raises(TypeError, match=r"Node 'a': rng must be a seeded random.Random .*got NoneType"):
        Node("a", cores=1, speed=1.0, rng=None)  # type: ignore[arg-type]
    rng = random.Random(5)
    assert Node("a", cores=1, speed=1.0, rng=rng).origin.rng is rng
