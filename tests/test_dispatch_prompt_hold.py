"""Reports of the instant held by the core (``Node.prompt_hold``): the
changes that follow the first within the hold go in one report, made when
the hold is over; an origin's view of itself stays exact at every change;
a robot that places nothing takes in only the reports it publishes; and the
driver publishes a report the core held at once, without holding it again."""

from __future__ import annotations

import random

from corehelpers import report

from ramps.core.config import RampsConfig
from ramps.core.events import ProgramFinished, PublishReport, Received, Send, StartProgram, Submit
from ramps.core.messages import OffloadRequest, decode
from ramps.core.node import Node

HOLD = 0.005


def _host(*, hold: float = HOLD, submits: bool = False) -> Node:
    n = Node("h", cores=2, speed=1.0, rng=random.Random(0), submits=submits, config=RampsConfig(probe_period=0.0))
    n.prompt_hold = hold
    return n


def _offer(n: Node, pid: str, now: float, work: float = 0.001) -> list:
    return n.handle(Received(sender="o", msg=OffloadRequest(program_id=pid, attempt=1, origin="o", host="h",
                                                            program="noop", work=work)), now)


def _reports(actions: list) -> list:
    return [a.report for a in actions if isinstance(a, PublishReport)]


def test_changes_within_the_hold_go_in_one_report_made_when_it_is_over() -> None:
    n = _host()
    assert _reports(_offer(n, "p1", 1.0)) == []
    assert n.next_deadline() is not None and n.next_deadline() <= 1.0 + HOLD
    assert _reports(n.handle(ProgramFinished(program_id="p1", attempt=1, ok=True), 1.001)) == []
    assert _reports(_offer(n, "p2", 1.002)) == []  # the hold runs from the first change, not the last
    assert n.next_deadline() == 1.0 + HOLD
    [report] = _reports(n.tick(1.0 + HOLD))
    assert (report.accepted_total, report.finished_total, report.ramps_running) == (2, 1, 1)
    assert _reports(n.tick(1.0 + 2 * HOLD)) == []  # nothing changed since
    assert _reports(n.handle(ProgramFinished(program_id="p2", attempt=1, ok=True), 1.02)) == []
    [after] = _reports(n.tick(1.02 + HOLD))
    assert after.finished_total == 2 and after.seq > report.seq


def test_without_a_hold_every_change_is_published_at_once() -> None:
    """The simulator's nodes (no hold): one report per change, as before."""
    n = _host(hold=0.0)
    assert [r.accepted_total for r in _reports(_offer(n, "p1", 1.0))] == [1]
    done = n.handle(ProgramFinished(program_id="p1", attempt=1, ok=True), 1.001)
    assert [r.finished_total for r in _reports(done)] == [1]


def test_an_origin_knows_what_its_own_robot_runs_at_every_change() -> None:
    n = _host(submits=True)
    n.tick(1.0)  # the report a submitter owes at once
    _offer(n, "p1", 1.1)
    assert n.view.ramps_programs("h") == 1  # before the hold is over
    _offer(n, "p2", 1.101)
    assert n.view.ramps_programs("h") == 2


def test_a_robot_that_places_nothing_takes_in_only_what_it_publishes() -> None:
    n = _host()
    seen = n.view.reports_received
    _offer(n, "p1", 1.0)
    _offer(n, "p2", 1.001)
    assert n.view.reports_received == seen  # no report built per change
    _reports(n.tick(1.0 + HOLD))
    assert n.view.reports_received == seen + 1 and n.view.ramps_programs("h") == 2


def test_becoming_an_origin_places_from_an_exact_view_of_itself() -> None:
    """A robot that ran a teammate's programs without taking them into its
    own view gets its first submission: it counts them before it places,
    so the program goes to the idle teammate, not onto its own full cores."""
    n = _host()
    n.tick(0.5)
    n.handle(Received(sender="o", msg=report("o", cores=2)), 0.5)
    n.tick(0.6)  # its own report, made with nothing running
    for i in range(2):
        _offer(n, f"p{i}", 1.0 + i / 1000, work=10.0)
    out = n.handle(Submit(program_id="mine", program="noop", work=1.0), 1.002)
    assert [(a.to, a.msg.attempt) for a in out if isinstance(a, Send) and isinstance(a.msg, OffloadRequest)] == [
        ("o", 1)]  # not first placed here on a view of nothing running, then turned away by its own executor
    assert not [a for a in out if isinstance(a, StartProgram) and a.program_id == "mine"]


def test_the_driver_publishes_a_report_the_core_held_at_once() -> None:
    """The node's driver gives its core the hold, so a report the core made
    when its hold was over is not held a second time."""
    from test_dispatch_path import _Pub

    from ramps.runtime import node as rn
    from ramps.runtime.node_reports import PROMPT_HOLD
    from ramps.runtime.settings import load_settings
    from ramps.testing.memory import FakeClock

    clock = FakeClock()
    rt = rn.NodeRuntime(load_settings(flags={"robot": "r1", "team": "t"}, environ={}), clock=clock)
    rt.node = Node("r1", cores=2, speed=1.0, rng=random.Random(0))
    rt.node.prompt_hold = PROMPT_HOLD
    pub = _Pub()
    rt.membership.load_pub, rt.membership.prompt_pub = _Pub(), pub
    rt.outbound.apply(_offer_actions(rt.node, clock.monotonic()))
    assert pub.sent == []
    clock.advance(PROMPT_HOLD)
    rt.outbound.apply([a for a in rt.node.tick(clock.monotonic()) if isinstance(a, PublishReport)])
    assert len(pub.sent) == 1 and decode(pub.sent[0]).msg.accepted_total == 1
    assert rt.outbound.held_due(clock.monotonic()) == float("inf")


def _offer_actions(n: Node, now: float) -> list:
    return [a for a in n.handle(Received(sender="o", msg=OffloadRequest(
        program_id="p1", attempt=1, origin="o", host="r1", program="noop", work=0.001)), now)
        if isinstance(a, PublishReport)]
