"""Fuzzing: every decoder and the core's event handling under hostile input.

How this works: hypothesis draws bytes (random, valid encodings of every
message type cut short, bit-flipped, edited and spliced, other protocol
versions, valid msgpack of the wrong shape, known message tags with random
fields, messages over the size limit, deep nesting) and checks the one
promise of ``decode``: it returns an ``Envelope`` or raises ``WireError``,
nothing else; what decodes re-encodes to the same message, and a version
error names both versions. For the core, hypothesis drives one ``Node`` with
valid but hostile messages from any sender (the node itself included),
replays of what it sent and heard, reordered batches, messages that came out
of the decoder, its own programs ending, peers lost and found, and time
moving on, then shuts it down as the runtime does; the node must never
raise, never deliver a program twice, never offer a ``local_only`` program
to another robot, and end with no program left active.

Rules: derandomized, no example database, a few thousand examples in all so
the file stays well under a minute; ``ramps bench fuzz`` is the long run
(100,000+ inputs, its own seeded generator) and is smoke-tested here too.
"""

from __future__ import annotations

import math
import random

import msgspec
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ramps.core import messages as m
from ramps.core.battery import BatteryMeasured
from ramps.core.events import (
    Cancel,
    PeerAlive,
    PeerLost,
    ProgramFinished,
    ProgressReported,
    Received,
    Submit,
)
from ramps.core.messages import PROTOCOL_VERSION, WireError, decode, encode
from ramps.core.policy import POLICIES
from ramps.bench.fuzz import CoreHarness, run_fuzz
from ramps.testing import hostile
from ramps.testing.hostile import ME

COMMON = dict(deadline=None, derandomize=True, database=None,
              suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large, HealthCheck.filter_too_much])
WIRE = settings(max_examples=400, **COMMON)
CORE = settings(max_examples=150, **COMMON)


def decodes_or_wire_error(data: bytes, **kw) -> m.Envelope | None:
    """The promise of ``decode``; a decoded message must survive a round trip."""
    try:
        env = decode(data, **kw)
    except WireError:
        return None
    # anything else propagates and fails the test
    again = decode(encode(env.sender, env.msg))
    assert again == env
    return env


# =================================================================== valid messages
key_safe = st.text(st.characters(blacklist_categories=("Cc", "Cs"), blacklist_characters="*$?#"),
                   min_size=1, max_size=m.MAX_NAME)
robots = st.sampled_from(["p", "q", ME, "r1", "o/app-1"]) | key_safe
names = st.sampled_from(["a", "b", "n#1", "route_plan"]) | st.text(st.characters(blacklist_categories=("Cs",)),
                                                                      min_size=1, max_size=m.MAX_NAME)
counts = st.integers(0, 10) | st.integers(0, 2**64 - 1)
amounts = st.floats(0.0, 1e300, allow_nan=False, allow_infinity=False)
loads = st.floats(0.0, m.MAX_LOAD, allow_nan=False)
texts = st.text(st.characters(blacklist_categories=("Cs",)), max_size=200)
words = st.sampled_from(["", "busy", "unknown_program", "bad_request", "closing", "program", "refused"])
payloads = st.binary(max_size=64)

reports = st.builds(
    m.LoadReport, robot=robots, incarnation=counts, seq=counts, cores=st.integers(1, m.MAX_CORES),
    speed=st.floats(m.MIN_SPEED, m.MAX_SPEED), cpu_busy=loads, runnable=loads, ramps_running=counts,
    ramps_avg=loads, accepted_total=counts, finished_total=counts, window=loads, mem_free=counts,
    cpu_per_core=st.lists(st.floats(0.0, 1.0), max_size=4), load_avg=loads,
    blacklisted=st.lists(robots, max_size=3), bad_messages=counts, sees=st.none() | counts,
    running=st.lists(st.builds(m.RunningProgram, names, robots, st.none() | st.floats(0.0, 1.0)), max_size=3),
    accelerators=st.lists(st.builds(m.AcceleratorSeen, names, st.integers(1, m.MAX_CORES),
                                    st.floats(m.MIN_SPEED, m.MAX_SPEED), counts, counts, counts,
                                    st.none() | st.floats(0.0, 1.0), st.lists(amounts, max_size=4)), max_size=2),
)
messages = st.one_of(
    reports,
    st.builds(m.OffloadRequest, program_id=names, attempt=counts, origin=robots, host=robots, program=names,
              args=payloads, payload_size=counts, work=amounts, expected_runnable=st.none() | amounts,
              force=st.booleans()),
    st.builds(m.OffloadAccepted, program_id=names, attempt=counts, host=robots, accept_seq=counts),
    st.builds(m.OffloadRejected, program_id=names, attempt=counts, host=robots, reason=words,
              permanent=st.booleans(), detail=texts, report=st.none() | reports),
    st.builds(m.Heartbeat, host=robots, incarnation=counts,
              programs=st.lists(st.builds(m.ProgramRef, names, counts), max_size=5)),
    st.builds(m.ProgramResult, program_id=names, attempt=counts, host=robots, ok=st.booleans(), value=payloads,
              error=texts, result_size=counts, retryable=st.booleans(), finish_seq=counts),
    st.builds(m.ResultAck, program_id=names, attempt=counts, origin=robots),
    st.builds(m.CancelProgram, program_id=names, attempt=counts, origin=robots),
    st.builds(m.SubmitProgram, client=robots, request_id=counts, program=names, args=payloads, work=amounts,
              result_size=counts, local_only=st.booleans(), policy=words),
    st.builds(m.CancelSubmitted, client=robots, request_id=counts),
    st.builds(m.ProgramOutcome, request_id=counts, ok=st.booleans(), value=payloads, error=texts,
              error_kind=words, host=st.just("") | robots, attempts=counts),
    st.builds(m.ProgramProgress, program_id=names, attempt=counts, host=robots, fraction=st.floats(0.0, 1.0),
              detail=texts),
    st.builds(m.ProgramUpdate, request_id=counts, state=words, host=st.just("") | robots, attempt=counts,
              fraction=st.none() | st.floats(0.0, 1.0), detail=texts),
)
encodings = st.builds(encode, robots, messages)

#: anything msgpack can carry: the wrong shape, nearly always
msgpack_values = st.recursive(
    st.none() | st.booleans() | st.integers(-(2**63), 2**64 - 1) | st.floats() | st.text(max_size=20)
    | st.binary(max_size=20) | st.sampled_from(["v", "type", "msg", "sender", "load", "ack", "offload"]),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(
        st.sampled_from(["v", "sender", "msg", "type", "host", "program_id", "attempt", "args"]) | st.text(max_size=8),
        inner, max_size=4),
    max_leaves=12,
)
TAGS = [cls.__struct_config__.tag for cls in (m.LoadReport, m.OffloadRequest, m.OffloadAccepted, m.OffloadRejected,
                                              m.Heartbeat, m.ProgramResult, m.ResultAck, m.CancelProgram,
                                              m.SubmitProgram, m.CancelSubmitted, m.ProgramOutcome,
                                              m.ProgramProgress, m.ProgramUpdate)]


# =================================================================== the wire decoder
@WIRE
@given(msg=messages, sender=robots)
def test_every_valid_message_round_trips(msg: m.Message, sender: str) -> None:
    env = decode(encode(sender, msg))
    assert env.msg == msg and env.sender == sender and env.v == PROTOCOL_VERSION


@WIRE
@given(data=st.binary(max_size=4096))
def test_random_bytes(data: bytes) -> None:
    decodes_or_wire_error(data)


@WIRE
@given(data=encodings, cut=st.integers(0, 10_000))
def test_truncated_valid_messages(data: bytes, cut: int) -> None:
    decodes_or_wire_error(data[:cut % max(1, len(data))])


@pytest.mark.slow
@WIRE
@given(data=encodings, flips=st.lists(st.tuples(st.integers(0, 10_000), st.integers(0, 7)), min_size=1, max_size=8))
def test_bit_flipped_valid_messages(data: bytes, flips) -> None:
    buf = bytearray(data)
    for i, bit in flips:
        buf[i % len(buf)] ^= 1 << bit
    decodes_or_wire_error(bytes(buf))


@WIRE
@given(data=encodings, edits=st.lists(st.tuples(st.integers(0, 10_000), st.sampled_from(["ins", "del", "set"]),
                                                  st.binary(min_size=1, max_size=6)), min_size=1, max_size=4))
def test_edited_valid_messages(data: bytes, edits) -> None:
    buf = bytearray(data)
    for i, op, chunk in edits:
        i %= len(buf) + 1
        if op == "ins":
            buf[i:i] = chunk
        elif op == "del":
            del buf[i:i + len(chunk)]
        elif i < len(buf):
            buf[i] = chunk[0]
    decodes_or_wire_error(bytes(buf))


@WIRE
@given(a=encodings, b=encodings, i=st.integers(0, 10_000), j=st.integers(0, 10_000))
def test_spliced_valid_messages(a: bytes, b: bytes, i: int, j: int) -> None:
    decodes_or_wire_error(a[:i % (len(a) + 1)] + b[j % (len(b) + 1):])


@pytest.mark.slow
@WIRE
@given(v=st.integers(-(2**63), 2**64 - 1).filter(lambda v: v != PROTOCOL_VERSION), msg=messages,
       body=st.none() | msgpack_values)
def test_other_versions_are_refused_naming_both(v: int, msg: m.Message, body) -> None:
    env = msgspec.to_builtins(m.Envelope(v=PROTOCOL_VERSION, sender="a", msg=msg), builtin_types=(bytes,))
    env["v"] = v
    if body is not None:
        env["msg"] = body  # another version may have any body at all
    with pytest.raises(WireError) as info:
        decode(msgspec.msgpack.encode(env))
    assert f"message is version {v}," in str(info.value)
    assert f"this node speaks version {PROTOCOL_VERSION}" in str(info.value)


@pytest.mark.slow
@WIRE
@given(value=msgpack_values)
def test_valid_msgpack_of_the_wrong_shape(value) -> None:
    decodes_or_wire_error(msgspec.msgpack.encode(value))


@pytest.mark.slow
@WIRE
@given(tag=st.sampled_from(TAGS), fields=st.dictionaries(
    st.sampled_from(["robot", "program_id", "attempt", "host", "origin", "program", "args", "cores", "speed",
                     "seq", "incarnation", "programs", "ok", "value", "client", "request_id", "work", "extra"]),
    msgpack_values, max_size=12), sender=msgpack_values | robots)
def test_known_message_types_with_random_fields(tag: str, fields: dict, sender) -> None:
    env = decodes_or_wire_error(msgspec.msgpack.encode({"v": PROTOCOL_VERSION, "sender": sender,
                                                        "msg": dict(fields, type=tag)}))
    if env is not None:  # whatever passed holds the schema's promises
        for name in ("attempt", "seq", "incarnation", "request_id"):
            assert getattr(env.msg, name, 0) >= 0


@WIRE
@given(data=st.binary(max_size=300) | encodings, limit=st.integers(0, 300))
def test_over_the_size_limit_is_refused_before_parsing(data: bytes, limit: int) -> None:
    if len(data) > limit:
        with pytest.raises(WireError, match="exceeds the limit"):
            decode(data, max_bytes=limit)
    else:
        decodes_or_wire_error(data, max_bytes=limit)


@pytest.mark.parametrize("depth", [10, 1_000, 100_000, 1_000_000])
@pytest.mark.parametrize("level", [b"\x91", b"\x81\xa1k"], ids=["arrays", "maps"])
@pytest.mark.parametrize("where", [b"", b"\x82\xa1v\x01\xa4junk",
                                   b"\x83\xa1v\x01\xa6sender\xa1p\xa3msg\x82\xa4type\xa4load\xa4junk"],
                         ids=["whole", "ignored-field", "inside-a-message"])
def test_deep_nesting(depth: int, level: bytes, where: bytes) -> None:
    with pytest.raises(WireError):
        decode(where + level * depth + b"\xc0")


def test_oversized_real_message() -> None:
    data = encode("p", m.OffloadRequest(program_id="a", attempt=1, origin="p", host="n", program="x",
                                        args=b"\x00" * m.MAX_MESSAGE_BYTES))
    with pytest.raises(WireError, match=f"exceeds the limit of {m.MAX_MESSAGE_BYTES} bytes"):
        decode(data)


# =================================================================== the core
PEERS = ["p", "q", ME, "o/app-1"]


def aimed(h: CoreHarness):
    """A message about one of the node's real programs (current or nearby
    attempt and host) or one it runs, so input reaches deep states."""
    programs, running = h.node.origin.programs, sorted(h.node.executor.running)
    options = [messages]
    if programs:
        @st.composite
        def about(draw):
            ap = programs[draw(st.sampled_from(sorted(programs)))]
            attempt = draw(st.sampled_from(sorted({ap.attempt, max(0, ap.attempt - 1), ap.attempt + 1, *ap.live})))
            host = draw(st.sampled_from(sorted({ap.host or "p", *ap.live.values(), "p", ME})))
            pid = ap.program_id
            return draw(st.one_of(
                st.builds(m.OffloadAccepted, program_id=st.just(pid), attempt=st.just(attempt), host=st.just(host),
                          accept_seq=counts),
                st.builds(m.OffloadRejected, program_id=st.just(pid), attempt=st.just(attempt), host=st.just(host),
                          reason=words, permanent=st.booleans(), report=st.none() | reports),
                st.builds(m.Heartbeat, host=st.just(host), incarnation=counts,
                          programs=st.just([m.ProgramRef(pid, attempt)])),
                st.builds(m.ProgramResult, program_id=st.just(pid), attempt=st.just(attempt), host=st.just(host),
                          ok=st.booleans(), retryable=st.booleans(), finish_seq=counts),
            ))
        options.append(about())
    if running:
        options.append(st.sampled_from(running).flatmap(lambda k: st.builds(
            m.CancelProgram, program_id=st.just(k[0]), attempt=st.just(k[1]), origin=st.sampled_from(PEERS))))
        options.append(st.sampled_from(running).flatmap(lambda k: st.builds(
            m.ResultAck, program_id=st.just(k[0]), attempt=st.just(k[1]), origin=st.sampled_from(PEERS))))
    return st.one_of(*options)


STEPS = ["hostile", "hostile", "aimed", "aimed", "replay_sent", "replay_heard", "reorder", "from_the_wire",
         "submit", "finish", "progress", "cancel", "peer", "tick", "to_deadline", "battery"]


deadlines = st.sampled_from(hostile.GOOD_DEADLINES + hostile.BAD_DEADLINES) | st.floats()


@pytest.mark.slow
@CORE
@given(policy=st.sampled_from(sorted(POLICIES)), seed=st.integers(0, 1000), data=st.data())
def test_core_survives_hostile_input_and_delivers_each_program_once(policy: str, seed: int, data) -> None:
    h = CoreHarness(random.Random(seed), policy)  # checks every action it is handed (see ramps.bench.fuzz)
    node = h.node
    n_submitted = 0
    for _ in range(data.draw(st.integers(0, 60), label="steps")):
        step = data.draw(st.sampled_from(STEPS))
        if step == "hostile":
            h._receive(data.draw(st.sampled_from(PEERS) | robots), data.draw(messages))
        elif step == "aimed":
            h._receive(data.draw(st.sampled_from(PEERS)), data.draw(aimed(h)))
        elif step == "replay_sent" and h.sent:
            to, msg = data.draw(st.sampled_from(list(h.sent)))
            h._receive(data.draw(st.sampled_from([to, ME, "p"])), msg)
        elif step == "replay_heard" and h.heard:
            h._receive(*data.draw(st.sampled_from(list(h.heard))))
        elif step == "reorder" and len(h.heard) > 1:
            for sender, msg in data.draw(st.permutations(list(h.heard)[-6:])):
                h._apply(node.handle(Received(sender=sender, msg=msg), h.now))
        elif step == "from_the_wire":
            raw = bytearray(encode(data.draw(robots), data.draw(aimed(h))))
            for i in data.draw(st.lists(st.integers(0, 10_000), max_size=2)):
                raw[i % len(raw)] ^= 0x01
            try:
                env = decode(bytes(raw))
            except WireError:
                continue
            if not isinstance(env.msg, (m.SubmitProgram, m.CancelSubmitted, m.ProgramOutcome, m.ProgramUpdate)):
                h._receive(env.sender, env.msg)
        elif step == "submit":  # with a deadline, valid or one the core must refuse (CoreHarness.submit)
            n_submitted += 1
            h.submit(Submit(program_id=f"n#{n_submitted}", program=data.draw(st.sampled_from(["route_plan", "x"])),
                            work=data.draw(st.floats(0.0, 1e6)), local_only=data.draw(st.booleans()),
                            payload_size=data.draw(st.integers(0, 10**9)),
                            policy=data.draw(st.sampled_from(["", "paper", "round_robin"])),
                            deadline=data.draw(deadlines) if data.draw(st.booleans()) else h.now + data.draw(
                                st.floats(-5.0, 100.0)),
                            on_miss=data.draw(st.sampled_from(["run", "local", "fail", *hostile.BAD_ON_MISS]))))
        elif step == "finish" and node.executor.running:
            pid, attempt = data.draw(st.sampled_from(sorted(node.executor.running)))
            ok = data.draw(st.booleans())
            h._apply(node.handle(ProgramFinished(program_id=pid, attempt=attempt, ok=ok,
                                                 retryable=not ok and data.draw(st.booleans())), h.now))
        elif step == "progress" and node.executor.running:  # any float a program may report
            pid, attempt = data.draw(st.sampled_from(sorted(node.executor.running)))
            h._apply(node.handle(ProgressReported(program_id=pid, attempt=attempt, fraction=data.draw(st.floats()),
                                                  detail=data.draw(texts)), h.now))
        elif step == "cancel" and node.origin.programs:
            h._apply(node.handle(Cancel(program_id=data.draw(st.sampled_from(sorted(node.origin.programs)))), h.now))
        elif step == "battery":  # any reading the driver may pass on (ramps.core.battery)
            h._apply(node.handle(BatteryMeasured(charge=data.draw(st.none() | st.floats()),
                                                 power=data.draw(st.none() | st.floats())), h.now))
        elif step == "peer":
            robot = data.draw(st.sampled_from(PEERS))
            h._apply(node.handle(PeerLost(robot=robot) if data.draw(st.booleans()) else PeerAlive(robot=robot), h.now))
        elif step == "tick":
            h.now += data.draw(st.floats(0.0, 15.0))
            h._apply(node.tick(h.now))
        elif step == "to_deadline":
            d = node.next_deadline()
            if d is not None:
                assert math.isfinite(d)
                h.now = max(h.now, d)
                h._apply(node.tick(h.now))
    h.shutdown()  # what the runtime does on SIGTERM: nothing may stay active
    assert all(n == 1 for n in h.delivered.values())
    assert node.statistics().delivered == sum(h.delivered.values())


def test_the_harness_catches_a_double_delivery() -> None:
    """The checks above must be able to fail (so they cannot pass vacuously)."""
    from ramps.core.events import Deliver

    h = CoreHarness(random.Random(0), "ramps")
    h.submitted.add("a")
    h._apply([Deliver(program_id="a", ok=True)])
    with pytest.raises(AssertionError, match="delivered twice"):
        h._apply([Deliver(program_id="a", ok=True)])
    h.local_only.add("b")
    with pytest.raises(AssertionError, match="local_only"):
        from ramps.core.events import Send

        h._apply([Send(to="p", msg=m.OffloadRequest(program_id="b", attempt=1, origin=ME, host="p", program="x"))])


def test_the_harness_catches_wrong_deadline_answers() -> None:
    """A miss flag that disagrees with the deadline, an offer the wire would
    refuse, a bad deadline taken: each is caught."""
    from ramps.core.events import Deliver, Send

    h = CoreHarness(random.Random(0), "ramps")
    h.submit(Submit(program_id="a", program="x", work=1.0, deadline=5.0))
    h.now = 6.0
    with pytest.raises(AssertionError, match="missed_deadline False"):
        h._apply([Deliver(program_id="a", ok=True)])
    with pytest.raises(AssertionError, match="wire refuses"):
        h._apply([Send(to="p", msg=m.OffloadRequest(program_id="a", attempt=1, origin=ME, host="p", program="x",
                                                    deadline_in=float("nan")))])
    h.submit(Submit(program_id="b", program="x", work=1.0, deadline=float("inf")))  # refused: counted
    assert h.refused == 1 and "b" not in h.node.origin.programs
    h.node.origin.submit = lambda sub, now, out: None  # a core that takes anything
    with pytest.raises(AssertionError, match="took a deadline of 'soon'"):
        h.submit(Submit(program_id="c", program="x", work=1.0, deadline="soon"))  # type: ignore[arg-type]


# =================================================================== the long run's generator
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_fuzz_benchmark_short_run_finds_nothing(seed: int) -> None:
    res = run_fuzz(inputs=4000, seed=seed, fresh_node_every=500)
    assert res["exceptions"] == 0, res["exception_samples"]
    assert (res["decoder_inputs"] + res["args_inputs"] + res["core_events"] + res["revocation_inputs"]
            == res["inputs"] == 4000)
    assert res["revocations_ok"] > 0 and res["revocations_refused"] > 0  # signed lists pass, the rest is refused
    assert res["decoded"] > 0 and res["wire_errors"] > 0 and res["core_from_decoder"] > 0
    assert res["programs_delivered"] > 0 and res["submits_refused"] > 0 and res["deadline_misses"] > 0
    kinds = {"truncated", "bit_flips", "wrong_version", "wrong_shape", "deep_nesting", "pickle", "bad_deadlines",
             "bad_battery"}
    assert kinds <= set(res["wire_kinds"])


def test_fuzz_benchmark_is_deterministic() -> None:
    strip = ("seconds", "inputs_per_s", "machine")
    a, b = (run_fuzz(inputs=1500, seed=5) for _ in range(2))
    assert {k: v for k, v in a.items() if k not in strip} == {k: v for k, v in b.items() if k not in strip}


def test_hostile_generators_replay_by_seed_and_only_ever_raise_wire_error():
    """The generators shipped in ``ramps.testing.hostile`` (for users' own
    tests): every kind of wire input, the same bytes for the same seed, and
    ``decode`` either accepts them or raises ``WireError``, nothing else."""
    from ramps.testing import WIRE_KINDS

    assert WIRE_KINDS is hostile.WIRE_KINDS and len(WIRE_KINDS) >= 10
    for name, _weight, make in WIRE_KINDS:
        first = [make(random.Random(i)) for i in range(30)]
        assert first == [make(random.Random(i)) for i in range(30)], name
        for data in first:
            assert isinstance(data, bytes), name
            try:
                decode(data)
            except WireError:
                pass
    oversized = hostile.oversized(random.Random(1))
    assert len(oversized) > m.MAX_MESSAGE_BYTES
    with pytest.raises(WireError):
        decode(oversized)
    msg = hostile.random_message(random.Random(3))
    data = encode(hostile.ME, msg)
    assert encode(hostile.ME, decode(data).msg) == data  # valid, and survives the round trip
