"""The wire schema's limits, and the core bugs that hostile input found.

How this works: messages are encoded (``encode`` checks nothing, as a
hostile sender's would not) and decoded; every field's declared limit must
turn into a ``WireError`` naming the field, and nothing else may escape
``decode``. A fake team whose every message crosses ``encode``/``decode``
shows that what honest nodes send always passes the schema. The last part
pins the core fixes found while fuzzing (each failed before its fix) and the
client bug outside this change (strict xfail).
"""

from __future__ import annotations

import random

import math
import threading
from concurrent.futures import Future

import msgspec
import pytest
from corehelpers import CFG, busy_origin_team, report, submit

from ramps.core import messages as m
from ramps.core.events import (
    Cancel,
    Deliver,
    ProgramFinished,
    Received,
    Send,
    StartProgram,
    Submit,
)
from ramps.core.loadview import report_problem
from ramps.core.messages import PROTOCOL_VERSION, WireError, decode, encode
from ramps.core.node import Node
from ramps.core.program import ProgramState
from ramps.testing import FakeTeam


def _raw(msg: dict, *, v: int = PROTOCOL_VERSION, sender=None) -> bytes:
    return msgspec.msgpack.encode({"v": v, "sender": "a" if sender is None else sender, "msg": msg})


def _body(msg: m.Message) -> dict:
    return msgspec.to_builtins(msg, builtin_types=(bytes,))


def _refused(data: bytes, match: str = "out of bounds") -> str:
    with pytest.raises(WireError, match=match) as info:
        decode(data)
    return str(info.value)


# =================================================================== versions
@pytest.mark.parametrize("other", [0, PROTOCOL_VERSION + 1, -1, 2**63 - 1, 2**64 - 1, -(2**63)])
def test_other_versions_are_named_with_ours(other: int) -> None:
    text = _refused(_raw(_body(m.ResultAck(program_id="p", attempt=1, origin="o")), v=other), "version")
    assert f"message is version {other}," in text
    assert f"this node speaks version {PROTOCOL_VERSION}" in text


def test_a_newer_version_with_an_unknown_body_is_still_a_version_error() -> None:
    text = _refused(_raw({"type": "teleport", "where": [1, 2], "nested": {"x": b"\x00"}}, v=PROTOCOL_VERSION + 1),
                    "version")
    assert f"version {PROTOCOL_VERSION + 1}" in text


def test_an_old_load_report_without_the_newer_fields_still_decodes() -> None:
    full = _body(report("r1"))
    for newer in ("bad_messages", "blacklisted", "cpu_per_core", "load_avg", "mem_free", "window", "sees",
                  "remaining"):
        full.pop(newer, None)
    env = decode(_raw(full, sender="r1"))
    assert env.msg.bad_messages == 0 and env.msg.blacklisted == [] and env.msg.sees is None


# =================================================================== per-field limits
ACK = _body(m.ResultAck(program_id="p", attempt=1, origin="o"))
REQ = _body(m.OffloadRequest(program_id="p", attempt=1, origin="o", host="h", program="burn"))
REP = _body(report("r1"))
RES = _body(m.ProgramResult(program_id="p", attempt=1, host="h", ok=True))
PRB = _body(m.LinkProbe(sent_at=1.0))
PRR = _body(m.LinkProbeReply(sent_at=1.0))
CLM = _body(m.BurstClaim(planned=True))


@pytest.mark.parametrize("body, field, value", [
    (ACK, "program_id", "p" * (m.MAX_NAME + 1)),
    (ACK, "program_id", ""),
    (ACK, "origin", ""),
    (ACK, "attempt", -1),
    (REQ, "program", "n" * (m.MAX_NAME + 1)),
    (REQ, "payload_size", -5),
    (REQ, "work", math.nan),
    (REQ, "work", math.inf),
    (REQ, "work", -1.0),
    (REQ, "expected_runnable", math.nan),
    (REQ, "expected_runnable", -0.5),
    (REQ, "time_budget", math.nan),
    (REQ, "time_budget", math.inf),
    (REQ, "time_budget", -1.0),
    (REP, "cores", 0),
    (REP, "cores", m.MAX_CORES + 1),
    (REP, "speed", 0.0),
    (REP, "speed", 1e-300),
    (REP, "speed", math.inf),
    (REP, "runnable", 1e300),
    (REP, "cpu_busy", math.nan),
    (REP, "ramps_avg", -1.0),
    (REP, "window", math.inf),
    (REP, "load_avg", math.nan),
    (REP, "seq", -1),
    (REP, "incarnation", -1),
    (REP, "accepted_total", -1),
    (REP, "mem_free", -1),
    (REP, "bad_messages", -1),
    (REP, "sees", -1),
    (REP, "cpu_per_core", [0.5] * (m.MAX_CORES + 1)),
    (REP, "cpu_per_core", [math.nan]),
    (PRB, "padding", b"\0" * (m.MAX_PROBE_BYTES + 1)),
    (PRB, "sent_at", math.nan),
    (PRB, "sent_at", -1.0),
    (PRR, "size", m.MAX_PROBE_BYTES + 1),
    (PRR, "size", -1),
    (RES, "work_done", math.nan),
    (RES, "work_done", -1.0),
    (RES, "work_done", math.inf),
    (REP, "remaining", [1.0] * (m.MAX_LISTED + 1)),
    (REP, "remaining", [math.nan]),
    (REP, "remaining", [-1.0]),
    (REP, "remaining", [math.inf]),
    (REP, "blacklisted", ["r2", "*"]),
    (CLM, "pools", [["g", "", [1.0]]] * (m.MAX_LISTED + 1)),
    (CLM, "pools", [["g", "", [math.nan]]]),
    (CLM, "pools", [["g", "", [-1.0]]]),
    (CLM, "pools", [["g", "", [1.0] * (m.MAX_LISTED + 1)]]),
    (CLM, "pools", [["*", "", [1.0]]]),
], ids=lambda x: x if isinstance(x, str) else None)
def test_field_limits_are_enforced_while_decoding(body: dict, field: str, value) -> None:
    bad = dict(body, **{field: value})
    text = _refused(_raw(bad, sender="r1"))
    assert f"$.msg.{field}" in text


@pytest.mark.parametrize("msg, field, size", [
    (m.OffloadRejected(program_id="p", attempt=1, host="h", reason="busy", permanent=False), "detail", m.MAX_TEXT),
    (m.OffloadRejected(program_id="p", attempt=1, host="h", reason="busy", permanent=False), "reason", m.MAX_NAME),
    (m.ProgramResult(program_id="p", attempt=1, host="h", ok=False), "error", m.MAX_TEXT),
    (m.ProgramOutcome(request_id=1, ok=False), "error", m.MAX_OUTCOME_TEXT),
    (m.SubmitProgram(client="c", request_id=1, program="burn"), "policy", m.MAX_NAME),
    (m.ProgramProgress(program_id="p", attempt=1, host="h", fraction=0.5), "detail", m.MAX_PROGRESS_TEXT),
    (m.ProgramUpdate(request_id=1, state="running"), "detail", m.MAX_PROGRESS_TEXT),
    (m.ProgramUpdate(request_id=1, state="running"), "state", m.MAX_NAME),
], ids=lambda x: x if isinstance(x, str) else None)
def test_texts_up_to_their_limit_pass_and_one_more_is_refused(msg: m.Message, field: str, size: int) -> None:
    ok = msgspec.structs.replace(msg, **{field: "é" * size})  # characters, not bytes
    assert decode(encode("a", ok)).msg == ok
    _refused(encode("a", msgspec.structs.replace(msg, **{field: "é" * (size + 1)})))


def test_lists_up_to_their_limit_pass_and_one_more_is_refused() -> None:
    hb = m.Heartbeat(host="h", incarnation=1, programs=[m.ProgramRef("p", 1)] * m.MAX_REFS)
    assert len(decode(encode("h", hb)).msg.programs) == m.MAX_REFS
    text = _refused(encode("h", msgspec.structs.replace(hb, programs=hb.programs + [m.ProgramRef("p", 2)])))
    assert "$.msg.programs" in text
    # a reference is [id, attempt]; an item after them (a later minor's) is ignored
    # (docs/wire-compatibility.md), one short is refused
    got = decode(_raw({"type": "heartbeat", "host": "h", "incarnation": 1, "programs": [["p", 1, "extra"]]}))
    assert got.msg.programs == [m.ProgramRef("p", 1)]
    _refused(_raw({"type": "heartbeat", "host": "h", "incarnation": 1, "programs": [["p"]]}),
             "malformed|out of bounds")


def test_work_left_on_accelerators_crosses_within_its_limits_and_older_reports_still_decode() -> None:
    seen = m.AcceleratorSeen("cuda", 1, 20.0, 2, 0, 0, None, [0.5, 30.0])
    rep = report("g", accelerators=[seen])
    assert decode(encode("g", rep)).msg.accelerators == [seen]
    # a node that does not tell the work left sends 7 items: it is [], as before
    body = _body(rep)
    body["accelerators"] = [["cuda", 1, 20.0, 2, 0, 0, None]]
    assert decode(_raw(body, sender="g")).msg.accelerators == [m.AcceleratorSeen("cuda", 1, 20.0, 2)]
    # one that did not know the item reads the rest (decoders ignore items past the fields they know)
    older = msgspec.defstruct("AcceleratorSeen", [("kind", str), ("count", int), ("speed", float), ("running", int),
                                                  ("memory_total", int), ("memory_free", int),
                                                  ("utilisation", float | None)], array_like=True, frozen=True)
    assert msgspec.msgpack.decode(msgspec.msgpack.encode(seen), type=older) == older("cuda", 1, 20.0, 2, 0, 0, None)
    # a report without accelerators is the bytes it was: the field is inside the records only
    assert b"accelerators" not in encode("r1", report("r1"))
    for bad in ([1.0] * (m.MAX_LISTED + 1), [math.nan], [-1.0], [math.inf]):
        body["accelerators"] = [["cuda", 1, 20.0, 2, 0, 0, None, bad]]
        assert "$.msg.accelerators[0]" in _refused(_raw(body, sender="g"))


@pytest.mark.parametrize("name", ["*", "**", "r1/*", "a$*", "what?", "r#1", "r\n1", "r1\n", "\x00", ""])
def test_robot_and_client_names_cannot_be_wildcards_or_control_characters(name: str) -> None:
    """Robot and client names become Zenoh key chunks: a node that answered
    an origin named '*' would publish to every robot's inbox."""
    _refused(encode(name, m.ResultAck(program_id="p", attempt=1, origin="o")))
    for msg in (m.ResultAck(program_id="p", attempt=1, origin=name),
                m.OffloadAccepted(program_id="p", attempt=1, host=name, accept_seq=0),
                m.CancelSubmitted(client=name, request_id=1),
                report(name)):
        _refused(encode("a", msg))


@pytest.mark.parametrize("name", ["r1", "o/app-1", "robot.é", "host-42_b", "x" * m.MAX_NAME])
def test_ordinary_names_pass(name: str) -> None:
    msg = m.SubmitProgram(client=name, request_id=1, program="prog#1 with spaces")
    assert decode(encode(name, msg)).msg == msg


def test_an_outcome_may_name_no_host_but_other_messages_must() -> None:
    outcome = m.ProgramOutcome(request_id=1, ok=False, error="refused", error_kind="refused", host="")
    assert decode(encode("r1", outcome)).msg == outcome
    _refused(encode("r1", m.OffloadAccepted(program_id="p", attempt=1, host="", accept_seq=0)))


def test_payloads_are_bounded_by_the_message_limit() -> None:
    big = m.ProgramResult(program_id="p", attempt=1, host="h", ok=True, value=b"\x01" * (m.MAX_MESSAGE_BYTES - 200))
    assert len(decode(encode("h", big)).msg.value) == m.MAX_MESSAGE_BYTES - 200
    over = encode("h", msgspec.structs.replace(big, value=b"\x01" * m.MAX_MESSAGE_BYTES))
    _refused(over, "exceeds the limit")
    # a receiver with a higher total limit still holds the field to the schema
    over = encode("h", msgspec.structs.replace(big, value=b"\x01" * (m.MAX_MESSAGE_BYTES + 1)))
    with pytest.raises(WireError, match=r"\$\.msg\.value"):
        decode(over, max_bytes=2 * m.MAX_MESSAGE_BYTES)


# =================================================================== nothing but WireError
@pytest.mark.parametrize("data", [
    _raw(dict(ACK, program_id="zz")).replace(b"\xa2zz", b"\xa2\xff\xfe"),
    b"\x81\xa1v\xa2\xc3\x28",                      # the key's value is not UTF-8
    b"\x82\xa1v\x01\xa4junk" + b"\x91" * 200_000 + b"\xc0",    # nested deeper than the interpreter allows
    b"\x91" * 200_000 + b"\xc0",
    b"\x82\xa1v\x01\xa6sender\xdb\xff\xff\xff\xff",  # declares 4 GiB of string
    b"\x82\xa1v\xd6\xff\x00\x00\x00\x01\xa1x\x01",   # a timestamp where the version goes
    b"\x82\xa1v\x01\xa6sender\xc7\x0c\xff" + b"\xff" * 12,  # a timestamp out of range
], ids=["bad-utf8-in-field", "bad-utf8-in-version", "deep-ignored-field", "deep", "huge-length",
        "ext-version", "bad-timestamp"])
def test_what_msgspec_lets_through_becomes_a_wire_error(data: bytes) -> None:
    with pytest.raises(WireError):
        decode(data)


def test_a_bad_string_is_explained() -> None:
    data = _raw(dict(ACK, origin="\u00e9")).replace(b"\xa2\xc3\xa9", b"\xa2\xc3\x28")
    assert "not UTF-8" in _refused(data, "malformed")


# =================================================================== honest traffic passes
class WireTeam(FakeTeam):
    """A FakeTeam whose every message crosses encode/decode on the way."""

    crossed = 0

    def apply(self, robot, actions):
        for a in actions:
            if isinstance(a, Send):
                env = decode(encode(robot, a.msg))
                assert env.msg == a.msg and env.sender == robot
                WireTeam.crossed += 1
        return super().apply(robot, actions)


def test_everything_an_honest_team_sends_passes_the_schema() -> None:
    team = WireTeam({"o": (1, 1.0), "a": (4, 2.0), "b": (4, 1.0)},
                    registry={"a": frozenset({"route_plan"}), "b": frozenset({"route_plan"})})
    team.nodes["o"].executor.background = 10.0
    team.publish()
    for n in team.nodes.values():  # load reports, with a blacklist and a busy-rejection report
        team.apply(n.robot, [Send(to="o", msg=n.make_report(cpu_busy=1.0, runnable=2.0, ramps_avg=1.0, window=1.0,
                                                           cpu_per_core=[0.5, 1.0], load_avg=0.5))])
    submit(team, "p1")
    submit(team, "p2", program="teleport")  # refused with a long, quoted reason
    team.deliver()
    for key in list(team.nodes["a"].executor.running):
        team.handle("a", ProgramFinished(program_id=key[0], attempt=key[1], ok=False, error="E" * 3000))
    team.deliver()
    team.advance(CFG.heartbeat_timeout + 1.0)
    team.deliver()
    assert WireTeam.crossed > 5
    assert [d.program_id for d in team.delivered("p1")] == ["p1"]
    assert team.delivered("p2")[0].error_kind == "refused"


# =================================================================== core fixes found by fuzzing
def test_extreme_but_finite_load_reports_are_anomalies_not_a_division_by_zero() -> None:
    """speed 1e-300 with a run queue of 1e300 made speed * share underflow to
    0.0, and every placement raised ZeroDivisionError (a report that the
    in-memory simulator path, which does not decode, could still deliver)."""
    for bad in ({"speed": 1e-300, "runnable": 1e300}, {"speed": 5e-324}, {"cores": m.MAX_CORES + 1},
                {"cpu_busy": 1e300}, {"speed": 1e300}):
        rep = report("p", **bad)
        assert report_problem(rep) is not None, bad
        node = Node("n", cores=2, speed=1.0, rng=random.Random(0))
        node.executor.background = 100.0
        node.handle(Received(sender="p", msg=rep), 0.0)
        assert node.statistics().anomalies == 1
        node.handle(Submit(program_id="a", program="x", work=1.0), 0.1)  # must not raise
    assert report_problem(report("p", speed=m.MIN_SPEED, runnable=m.MAX_LOAD, cores=m.MAX_CORES)) is None


@pytest.mark.parametrize("policy", ["ramps", "paper"])
@pytest.mark.parametrize("work", [math.nan, -1.0, math.inf])
def test_submit_with_impossible_work_is_refused_before_any_state_changes(policy: str, work: float) -> None:
    """NaN work made every policy's choice fail (min() of nothing, choice
    from nothing) after the program was registered, leaving it stuck."""
    node = Node("n", cores=2, speed=1.0, policy=policy, rng=random.Random(0))
    with pytest.raises(ValueError, match="work must be finite"):
        node.handle(Submit(program_id="a", program="x", work=work), 0.0)
    assert node.origin.programs == {} and node.statistics().active_programs == 0


@pytest.mark.parametrize("local_only", [True, False])
def test_shutting_down_with_its_own_program_running_locally_terminates(local_only: bool) -> None:
    """A node handing its programs back at shutdown re-offered its own local
    program to its own closing executor, which turned it away, forever (the
    driver thread spun, and its action list grew without bound)."""
    node = Node("n", cores=2, speed=1.0, rng=random.Random(0))
    node.handle(Submit(program_id="a", program="x", work=1.0, local_only=local_only), 0.0)
    out: list = []
    assert node.executor.hand_back(1.0, out) == 1
    actions = node._loopback(out, 1.0)  # returned: no endless loop
    assert node.origin.programs["a"].state is ProgramState.BACKOFF
    assert not [a for a in actions if isinstance(a, Send)], "nothing may leave a robot alone in its team"
    later = node.tick(1.0 + CFG.backoff_max)  # retries stay finite, one per back-off
    assert [a.what for a in later if hasattr(a, "what")].count("backoff") == 1
    [d] = [a for a in node.handle(Cancel(program_id="a"), 5.0) if isinstance(a, Deliver)]
    assert d.error_kind == "cancelled"


# =================================================================== unregistered and local_only programs
def test_a_host_refuses_a_program_it_has_not_registered_with_a_clear_error_over_the_wire() -> None:
    team = WireTeam({"o": (1, 1.0), "a": (4, 2.0)}, registry={"a": frozenset({"route_plan"})})
    team.nodes["o"].executor.background = 10.0
    team.publish()
    submit(team, "p", program="drive_arm")
    team.deliver()
    assert not team.actions(StartProgram, "a")
    [d] = team.delivered("p")
    assert (d.ok, d.error_kind, d.host) == (False, "refused", "a")
    assert "no program 'drive_arm' is registered on a" in d.error


def test_a_local_only_program_never_leaves_its_robot_even_when_swamped_or_failing() -> None:
    team = busy_origin_team()  # o is swamped, a and b are idle and fast
    submit(team, "p", local_only=True)
    team.deliver()
    for _ in range(3):  # its worker dies under it, again and again
        [key] = list(team.nodes["o"].executor.running)
        team.handle("o", ProgramFinished(program_id=key[0], attempt=key[1], ok=False, retryable=True, error="oom"))
        team.deliver()
    team.advance(CFG.heartbeat_timeout * 3)
    [key] = list(team.nodes["o"].executor.running)
    team.handle("o", ProgramFinished(program_id=key[0], attempt=key[1], ok=True, value=b"\x01"))
    team.deliver()
    assert [d.host for d in team.delivered("p")] == ["o"]
    assert not any(isinstance(a, Send) and isinstance(a.msg, m.OffloadRequest) for _t, _r, a in team.log)
    assert not team.actions(StartProgram, "a") and not team.actions(StartProgram, "b")


# =================================================================== outside this change
def test_a_garbage_result_value_fails_the_future_instead_of_hanging_it() -> None:
    from ramps.runtime.client import Team
    from ramps.runtime.pending import Pending
    from ramps.runtime.transport import REAL_CLOCK

    team = Team.__new__(Team)
    team._lock = threading.Lock()
    fut: Future = Future()
    fut.program = "echo"  # type: ignore[attr-defined]
    team._pending = Pending(team._lock, REAL_CLOCK, send=lambda data: None, reachable=lambda: True,
                            withdraw=lambda rid: None)
    team._pending.futures[7] = fut  # type: ignore[assignment]
    team._on_outcome(encode("r1", m.ProgramOutcome(request_id=7, ok=True, value=b"\xc1", host="r1")))
    assert fut.done()
    with pytest.raises(Exception, match="could not be decoded"):
        fut.result()


def test_a_node_drops_and_counts_what_exceeds_its_backlog(monkeypatch) -> None:
    """A flood faster than the driver cannot grow the node's memory without bound."""
    import ramps.runtime.node as rn
    from ramps.runtime.settings import load_settings

    monkeypatch.setattr(rn, "MAX_BACKLOG_BYTES", 1000)
    node = rn.NodeRuntime(load_settings(flags={"robot": "r1", "team": "t"}, environ={}))
    for _ in range(30):
        node._on_wire(b"x" * 100)
    assert node.intake.backlog == 1000 and node.intake.overflow == 20
    node.inbound.handle(node._q.get_nowait(), 0.0)  # the driver takes one: room for one more
    assert node.intake.backlog == 900 and node.bad_messages == 1
    node._on_wire(b"y" * 100)
    assert node.intake.overflow == 20 and node.intake.backlog == 1000


@pytest.mark.parametrize("fraction", [-0.01, 1.01, math.nan, math.inf, -math.inf])
def test_progress_is_a_fraction_between_0_and_1(fraction: float) -> None:
    """A host's progress and a node's update carry a fraction 0..1; anything
    else (NaN, infinities, out of range) is refused by the decoder."""
    for msg in (m.ProgramProgress(program_id="p", attempt=1, host="h", fraction=0.5),
                m.ProgramUpdate(request_id=1, state="progress", host="h", fraction=0.5)):
        for ok in (0.0, 0.42, 1.0):
            good = msgspec.structs.replace(msg, fraction=ok)
            assert decode(encode("h", good)).msg == good
        text = _refused(encode("h", msgspec.structs.replace(msg, fraction=fraction)))
        assert "$.msg.fraction" in text
    # an update before any progress has none; its host may be empty (not placed yet)
    assert decode(encode("n", m.ProgramUpdate(request_id=3, state="placed"))).msg.fraction is None
    _refused(encode("n", m.ProgramProgress(program_id="p", attempt=1, host="*", fraction=0.5)))


def test_a_load_report_lists_at_most_max_listed_running_programs() -> None:
    rep = msgspec.structs.replace(report("r1"), running=[m.RunningProgram("route_plan", "r2", 0.5)] * m.MAX_LISTED)
    assert decode(encode("r1", rep)).msg.running[0] == m.RunningProgram("route_plan", "r2", 0.5)
    text = _refused(encode("r1", msgspec.structs.replace(rep, running=rep.running + [m.RunningProgram("p", "o")])))
    assert "$.msg.running" in text
    for bad in (m.RunningProgram("p", "o", 1.5), m.RunningProgram("p", "*"), m.RunningProgram("", "o")):
        _refused(encode("r1", msgspec.structs.replace(rep, running=[bad])))


def test_a_load_report_lists_at_most_max_listed_links_and_learned_programs() -> None:
    rep = msgspec.structs.replace(report("r1"), links=[m.LinkSeen("r2", 0.05, 1e6, 0.67)] * m.MAX_LISTED,
                                  learned=[m.LearnedWork("route_plan", 4.2)] * m.MAX_LISTED)
    back = decode(encode("r1", rep)).msg
    assert back.links[0] == m.LinkSeen("r2", 0.05, 1e6, 0.67) and back.learned[0] == m.LearnedWork("route_plan", 4.2)
    assert decode(encode("r1", msgspec.structs.replace(rep, links=[m.LinkSeen("r2")]))).msg.links[0].latency is None
    for field, extra in (("links", m.LinkSeen("r3")), ("learned", m.LearnedWork("p", 1.0))):
        text = _refused(encode("r1", msgspec.structs.replace(rep, **{field: getattr(rep, field) + [extra]})))
        assert f"$.msg.{field}" in text
    for bad in (dict(links=[m.LinkSeen("*", 0.1, 1.0)]), dict(links=[m.LinkSeen("r2", -0.1, 1.0)]),
                dict(links=[m.LinkSeen("r2", 0.1, math.inf)]), dict(links=[m.LinkSeen("r2", None, None, -1.0)]),
                dict(learned=[m.LearnedWork("", 1.0)]),
                dict(learned=[m.LearnedWork("p", -1.0)]), dict(learned=[m.LearnedWork("p", math.nan)])):
        _refused(encode("r1", msgspec.structs.replace(rep, **bad)))


def test_a_checkpoint_is_at_most_max_checkpoint_bytes() -> None:
    """A program's saved state travels host -> origin (ProgramCheckpoint) and
    origin -> new host (OffloadRequest.resume), each within the same limit."""
    cp = m.ProgramCheckpoint(program_id="p", attempt=1, host="h", state=b"s" * m.MAX_CHECKPOINT_BYTES, fraction=0.5)
    assert decode(encode("h", cp)).msg == cp
    assert "$.msg.state" in _refused(encode("h", msgspec.structs.replace(cp, state=cp.state + b"s")))
    assert "$.msg.fraction" in _refused(encode("h", msgspec.structs.replace(cp, fraction=1.5)))
    req = m.OffloadRequest(program_id="p", attempt=2, origin="o", host="h", program="burn", resume=cp.state,
                           resume_fraction=0.5)
    assert decode(encode("o", req)).msg == req
    assert "$.msg.resume" in _refused(encode("o", msgspec.structs.replace(req, resume=cp.state + b"s")))
    assert "$.msg.resume_fraction" in _refused(encode("o", msgspec.structs.replace(req, resume_fraction=-0.1)))
