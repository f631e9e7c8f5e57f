"""Periodic load reports in a large team (``RampsConfig.report_rate``): each
robot's go on the wire less often, so an origin hears a bounded number a
second, and a change still goes at once. The real driver and core over the
in-memory bus (``ramps.testing.memory``)."""

from __future__ import annotations

import pytest

from ramps.core.config import RampsConfig
from ramps.core.events import Received
from ramps.core.messages import (KNOWN_TYPES, Heartbeat, LinkProbeReply, LoadReport, OffloadAccepted,
                                 OffloadRejected, ProgramProgress, ProgramRef, ProgramResult, ResultAck, encode)
from ramps.core.wirepeek import WAIT_TAGS, can_wait
from ramps.runtime import keys
from ramps.core.cadence import moved
from ramps.testing.memory import MemoryTeam


def test_period_grows_with_the_team_up_to_a_bound() -> None:
    assert RampsConfig().report_rate == 32.0 and RampsConfig.paper().report_rate == 0.0
    assert RampsConfig.paper().report_period(1.0, 999) == 1.0  # the paper's: every period
    c = RampsConfig(report_rate=32.0)
    assert c.report_period(1.0, 4) == 1.0
    assert c.report_period(1.0, 32) == 1.0  # an origin of 33 robots hears 32 a second
    assert c.report_period(1.0, 64) == pytest.approx(2.0)
    # never as old as a view holds stale: three quarters of relocate_stale (4 s)
    assert c.report_period(1.0, 999) == pytest.approx(3.0)
    assert RampsConfig(report_rate=32.0, relocate_stale=2.0).report_period(1.0, 999) == pytest.approx(1.5)
    assert RampsConfig(report_rate=0).report_period(1.0, 999) == 1.0
    assert c.report_period(5.0, 999) == 5.0  # never more often than the publisher's own period


def _report(**kw) -> LoadReport:
    base = dict(robot="r2", incarnation=1, seq=1, cores=2, speed=1.0, cpu_busy=0.1, runnable=0.2,
                ramps_running=0, ramps_avg=0.0, accepted_total=0, finished_total=0, sees=3)
    return LoadReport(**{**base, **kw})


def test_what_moves_a_report_out_at_once() -> None:
    sent = _report()
    assert not moved(sent, _report(seq=9, cpu_busy=0.9, runnable=1.6, load_avg=1.0))  # load: within the period
    for change in (dict(accepted_total=1), dict(finished_total=1), dict(ramps_running=1), dict(sees=2),
                   dict(speed=1.2), dict(cores=1), dict(low_battery=True), dict(blacklisted=["r3"]),
                   dict(incarnation=2), dict(submits=True)):
        assert moved(sent, _report(**change)), change


def _team(rate: float) -> MemoryTeam:
    return MemoryTeam({f"r{i}": (1, 1.0) for i in range(1, 6)}, settings={"core": {"report_rate": rate}})


def _periodic_heard(listener) -> int:
    return sum(n for key, n in listener.heard.items() if "/load/" in key and not key.endswith("/now"))


def test_a_large_team_reports_less_often_and_a_change_goes_at_once() -> None:
    """Four teammates and a rate of one report a second: every 3 s instead of every 1 s."""
    every, bounded = _team(0.0), _team(1.0)
    try:
        listeners = {}
        for t in (every, bounded):
            t.run(5.0)
            listeners[id(t)] = app = t.bus.transport("listener")  # hears the periodic reports, as an application
            app.subscribe(keys.load(t.team), lambda data: None)
            t.run(12.0)
        n_every, n_bounded = (_periodic_heard(listeners[id(t)]) for t in (every, bounded))
        assert n_every >= 5 * 11  # five robots, one a second
        assert n_bounded <= n_every / 2.5
        # a teammate's node stops: the others' view of the team changed, their reports go at the next
        # publish (every second) instead of waiting for their 3 s
        before = _periodic_heard(listeners[id(bounded)])
        at = bounded.clock.t
        bounded.kill("r5")
        bounded.run(1.05)
        went = _periodic_heard(listeners[id(bounded)]) - before
        assert went >= 4, f"{went} reports within {bounded.clock.t - at:.1f} s of a teammate going"
    finally:
        every.close()
        bounded.close()


def test_a_teammates_periodic_report_waits_for_the_next_round_without_waking_it() -> None:
    """On a robot that places programs, a teammate's periodic report is held
    (``WireIntake.later``), not queued: it wakes no round of the driver, and
    the next round reads it first. A report of the instant still wakes it."""
    team = MemoryTeam({"r1": (1, 1.0), "r2": (1, 1.0)})
    try:
        app = team.connect("r1")  # r1 places programs: it hears r2's periodic reports
        team.run(3.0)
        r1, r2 = team.nodes["r1"], team.nodes["r2"]
        assert r1.membership.wide
        seq = r1.node.view.report_of("r2").seq
        r2.reports.cadence.sent = None  # its next periodic report goes on the wire
        r2.reports.publish(r2._clock())
        assert len(r1.intake.later) == 1 and r1._q.empty()  # held, and nothing woke r1
        r1.step()
        assert not r1.intake.later and r1.node.view.report_of("r2").seq > seq
        r2.node.executor.accepted_total += 1  # its programs changed: a report of the instant
        r2.reports.publish_prompt(r2.node.current_report())
        assert not r1._q.empty() and not r1.intake.later
        app.close()
    finally:
        team.close()


def test_messages_that_can_wait_are_told_by_their_bytes_alone() -> None:
    """Heartbeats, acceptances, acknowledgements and progress wait for the driver's next round;
    a result, an offer's refusal, a report or a probe's reply wakes it."""
    wait = [Heartbeat(host="r2", incarnation=7, programs=[ProgramRef(program_id="p", attempt=1)]),
            OffloadAccepted(program_id="p", attempt=1, host="r2", accept_seq=1),
            ResultAck(program_id="p", attempt=1, origin="r1"),
            ProgramProgress(program_id="p", attempt=1, host="r2", fraction=0.5)]
    wake = [_report(robot="heartbeat"), LinkProbeReply(sent_at=1.0), ProgramResult(program_id="accept", attempt=1,
                                                                                    host="h", ok=True),
            OffloadRejected(program_id="heartbeat", attempt=1, reason="busy", host="h", permanent=False)]
    assert {type(m).__struct_config__.tag for m in wait} == set(WAIT_TAGS) <= KNOWN_TYPES
    for sender in ("r2", "x" * 31, "x" * 128, "ロボット" * 32, "heartbeat", "¤type©heartbeat", "£msg\x84¤type©ack"):
        for msg in wait:
            assert can_wait(encode(sender, msg)), (sender, msg)
        for msg in wake:
            assert not can_wait(encode(sender, msg)), (sender, msg)
    # a result whose value spells a heartbeat's head is not one; nor are bytes cut short
    trap = b"\x83\xa1v\x01\xa6sender\xa2r2\xa3msg\x84\xa4type\xa9heartbeat"
    assert not can_wait(encode("r2", ProgramResult(program_id="p", attempt=1, host="h", ok=True, value=trap)))
    beat = encode("r2", wait[0])
    end = beat.index(b"heartbeat") + len(b"heartbeat")  # cut before its tag ends: not told (decoding refuses it)
    assert not any(can_wait(beat[:n]) for n in range(end)) and can_wait(beat[:end])
    assert not can_wait(b"") and not can_wait(b"\x83\xa1v\x02" + beat[4:])  # another major: read at once


def test_a_heartbeat_waits_for_the_next_round_and_counts_from_its_arrival() -> None:
    """An origin reads its hosts' heartbeats at the driver's next round (two a
    second from each host: waking for each cost more than reading it); the
    core is told when each arrived, so a program's silence counts from then."""
    team = MemoryTeam({"r1": (1, 1.0), "r2": (1, 1.0)})
    try:
        team.run(2.0)
        r1 = team.nodes["r1"]
        r1._on_wire(encode("r2", Heartbeat(host="r2", incarnation=1, programs=[])))
        assert len(r1.intake.later) == 1 and r1._q.empty()  # held, and nothing woke r1
        seen: list[Received] = []
        handle = r1.node.handle
        r1.node.handle = lambda event, now: (seen.append(event), handle(event, now))[1]  # type: ignore[method-assign]
        team.clock.advance(0.3)
        r1.step()
        assert not r1.intake.later
        [got] = [e for e in seen if isinstance(e, Received) and isinstance(e.msg, Heartbeat)]
        assert got.at == pytest.approx(r1._clock() - 0.3, abs=1e-6)
    finally:
        team.close()
