"""Edge cases of the origin found by reading the state machine against real timelines."""

from __future__ import annotations

import random

from ramps.core.config import RampsConfig
from ramps.core.events import Deliver, Note, ProgramFinished, Received, Send, Submit
from ramps.core.messages import CancelProgram, OffloadAccepted, ProgramResult, ResultAck
from ramps.core.node import Node


def report(node: Node, now: float):
    return node.make_report(cpu_busy=0.0, runnable=0.0, ramps_avg=0.0, window=1.0)


def setup_pair(**kw):
    cfg = RampsConfig(backoff_max=5.0, **kw)
    a = Node("a", cores=1, speed=1.0, config=cfg, rng=random.Random(0))
    b = Node("b", cores=4, speed=1.0, config=cfg, rng=random.Random(0))
    a.handle(Received(sender="a", msg=report(a, 0.0)), 0.0)
    a.handle(Received(sender="b", msg=report(b, 0.0)), 0.0)
    # a already runs one program itself, so the next one goes to b
    a.handle(Submit(program_id="a#0", program="p", work=100.0), 0.0)
    acts = a.handle(Submit(program_id="a#1", program="p", work=100.0), 0.0)
    sends = [x for x in acts if isinstance(x, Send)]
    assert sends and sends[0].to == "b"
    return a, b


def test_late_result_during_backoff_is_acknowledged_and_delivered():
    """b fell silent and was written off; its copy ran on all the same (a
    starved robot, a frozen one that thawed): its result is the program's."""
    a, _ = setup_pair()
    a.handle(Received(sender="b", msg=OffloadAccepted(program_id="a#1", attempt=1, host="b", accept_seq=1)), 0.1)
    a.tick(0.1 + a.config.heartbeat_timeout + 0.01)
    assert a.origin.programs["a#1"].state == "backoff"
    acts = a.handle(Received(sender="b", msg=ProgramResult(program_id="a#1", attempt=1, host="b", ok=True,
                                                           value=b"late")), 2.5)
    assert any(isinstance(x, Send) and isinstance(x.msg, ResultAck) for x in acts)
    assert [(d.ok, d.value, d.host) for d in acts if isinstance(d, Deliver)] == [(True, b"late", "b")]
    assert a.origin.programs["a#1"].state == "done" and a.origin.discarded == 0
    later = a.tick(20.0)  # past the back-off: nothing placed again, nothing delivered twice
    assert not [x for x in later if isinstance(x, Deliver) or isinstance(x, Send) and x.to == "b"]


def test_a_written_off_copy_heard_again_is_wanted_beside_the_new_one():
    a, _ = setup_pair()
    a.handle(Received(sender="b", msg=OffloadAccepted(program_id="a#1", attempt=1, host="b", accept_seq=1)), 0.1)
    a.tick(0.1 + a.config.heartbeat_timeout + 0.01)
    from ramps.core.messages import Heartbeat, ProgramRef

    acts = a.handle(Received(sender="b", msg=Heartbeat(host="b", incarnation=0,
                                                        programs=[ProgramRef("a#1", 1)])), 2.6)
    assert not any(isinstance(x, Send) and isinstance(x.msg, CancelProgram) for x in acts)
    assert [x.what for x in acts if isinstance(x, Note)] == ["revived"]
    assert a.origin.programs["a#1"].live.get(1) == "b"
    # its next heartbeats, still backing off, are those of a copy kept: no anomaly
    for t in (3.1, 3.6):
        a.handle(Received(sender="b", msg=Heartbeat(host="b", incarnation=0, programs=[ProgramRef("a#1", 1)])), t)
    assert a.origin.anomalies == 0
    # placed again after the back-off, the first result (b's) is delivered once and the new copy stopped
    a.tick(12.0)
    assert a.origin.programs["a#1"].state == "running" and a.origin.programs["a#1"].attempt == 2
    acts = a.handle(Received(sender="b", msg=ProgramResult(program_id="a#1", attempt=1, host="b", ok=True)), 13.0)
    assert [d.host for d in acts if isinstance(d, Deliver)] == ["b"] and a.origin.anomalies == 0


def test_late_result_during_backoff_is_acknowledged_and_discarded_as_in_the_paper():
    a, _ = setup_pair(late_results=False)
    a.handle(Received(sender="b", msg=OffloadAccepted(program_id="a#1", attempt=1, host="b", accept_seq=1)), 0.1)
    # b goes silent: heartbeat timeout -> blacklisted, backing off
    acts = a.tick(0.1 + a.config.heartbeat_timeout + 0.01)
    assert any(isinstance(x, Note) and x.what == "backoff" for x in acts)
    assert a.origin.programs["a#1"].state == "backoff"
    # then b's result for the written-off attempt arrives
    acts = a.handle(Received(sender="b", msg=ProgramResult(program_id="a#1", attempt=1, host="b", ok=True)), 2.5)
    assert any(isinstance(x, Send) and isinstance(x.msg, ResultAck) for x in acts), "host would resend forever"
    assert not any(isinstance(x, Deliver) for x in acts)
    assert a.origin.anomalies == 0
    assert a.origin.discarded == 1


def test_heartbeat_for_written_off_attempt_cancels_the_stray_copy_as_in_the_paper():
    a, _ = setup_pair(late_results=False)
    a.handle(Received(sender="b", msg=OffloadAccepted(program_id="a#1", attempt=1, host="b", accept_seq=1)), 0.1)
    a.tick(0.1 + a.config.heartbeat_timeout + 0.01)
    from ramps.core.messages import Heartbeat, ProgramRef

    acts = a.handle(Received(sender="b", msg=Heartbeat(host="b", incarnation=0,
                                                        programs=[ProgramRef("a#1", 1)])), 2.6)
    assert any(isinstance(x, Send) and isinstance(x.msg, CancelProgram) and x.to == "b" for x in acts)
    assert a.origin.anomalies == 0


def test_finished_programs_are_forgotten_after_the_retention_period():
    cfg = RampsConfig(result_retention=60.0)
    a = Node("a", cores=4, speed=1.0, config=cfg, rng=random.Random(0))
    a.handle(Received(sender="a", msg=report(a, 0.0)), 0.0)
    for i in range(3):
        a.handle(Submit(program_id=f"a#{i}", program="p", work=1.0), 0.0)
        acts = a.handle(ProgramFinished(
            program_id=f"a#{i}", attempt=1, ok=True), 1.0)
        assert any(isinstance(x, Deliver) for x in acts)
    assert len(a.origin.programs) == 3
    a.tick(30.0)
    assert len(a.origin.programs) == 3  # still settling late results
    a.tick(62.0)
    assert a.origin.programs == {}  # a long-running node does not grow forever
    # a very late result is still acknowledged, counted as an anomaly, never delivered
    acts = a.handle(Received(sender="b", msg=ProgramResult(program_id="a#0", attempt=1, host="b", ok=True)), 70.0)
    assert any(isinstance(x, Send) and isinstance(x.msg, ResultAck) for x in acts)
    assert not any(isinstance(x, Deliver) for x in acts)
