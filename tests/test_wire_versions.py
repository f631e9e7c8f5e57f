"""The wire-compatibility policy at the decoder and at a node's driver.

How this works: hand-made envelopes (msgpack of plain dicts, as a node of
another release would send) go through ``decode``: fields this release does
not know are ignored wherever they are, a message type it does not know is
``UnknownMessageType``, another major is ``VersionRefused`` naming both
versions, and garbage is still garbage. Then real node drivers on the
in-memory bus (``MemoryTeam``) count refusals and unknown types among the
dropped messages and apart, log each robot's version once (never as
malformed), and keep working.
docs/wire-compatibility.md is the policy.
"""

from __future__ import annotations

import logging

import msgspec
import pytest

import ramps
from ramps.core import messages as m
from ramps.runtime import keys
from ramps.testing.memory import MemoryTeam

ACK = {"type": "ack", "program_id": "p", "attempt": 1, "origin": "o"}


def raw(v=m.PROTOCOL_MAJOR, sender="a", msg=None, **envelope) -> bytes:
    return msgspec.msgpack.encode({"v": v, "sender": sender, "msg": ACK if msg is None else msg, **envelope})


def test_the_version_is_major_minor_and_the_envelope_carries_the_major() -> None:
    assert m.PROTOCOL == f"{m.PROTOCOL_MAJOR}.{m.PROTOCOL_MINOR}"
    assert m.PROTOCOL_VERSION == m.PROTOCOL_MAJOR
    assert msgspec.msgpack.decode(m.encode("a", m.ResultAck(program_id="p", attempt=1, origin="o"))) == {
        "v": m.PROTOCOL_MAJOR, "sender": "a", "msg": ACK}
    assert ramps.__version__ == "0.2.0"


@pytest.mark.parametrize("data", [
    raw(msg={**ACK, "since_1_2": [1, {"x": b"y"}]}),                           # in a message
    raw(hops=3, signature=b"\x00" * 64),                                       # in the envelope
    raw(msg={"type": "heartbeat", "host": "h", "incarnation": 1,
             "programs": [["p", 1, "a later minor's trailing item"]]}),       # in an array-like record
    raw(msg={"type": "reject", "program_id": "p", "attempt": 1, "host": "h", "reason": "busy",
             "permanent": False, "report": {"type": "load", "robot": "h", "incarnation": 1, "seq": 1,
                                            "cores": 1, "speed": 1.0, "cpu_busy": 0.0, "runnable": 0.0,
                                            "ramps_running": 0, "ramps_avg": 0.0, "accepted_total": 0,
                                            "finished_total": 0, "gpu": {"count": 1}}}),  # nested
])
def test_fields_a_node_does_not_know_are_ignored(data: bytes) -> None:
    env = m.decode(data)
    assert env.sender == "a" and type(env.msg).__struct_config__.tag in m.KNOWN_TYPES


def test_known_fields_keep_every_limit_beside_unknown_ones() -> None:
    with pytest.raises(m.WireError, match="out of bounds"):
        m.decode(raw(msg={**ACK, "origin": "o" * (m.MAX_NAME + 1), "extra": 1}))
    with pytest.raises(m.WireError, match="malformed"):
        m.decode(raw(msg={"type": "ack", "program_id": "p", "origin": "o", "extra": 1}))  # missing attempt
    with pytest.raises(m.WireError):
        m.decode(raw(sender="*", extra=1))  # a wildcard sender is still refused


def test_an_unknown_message_type_is_skipped_not_malformed() -> None:
    with pytest.raises(m.UnknownMessageType) as info:
        m.decode(raw(sender="r9", msg={"type": "gossip", "rumours": [1, 2, 3]}))
    assert isinstance(info.value, m.WireError)  # every caller that drops WireError still drops it
    assert (info.value.tag, info.value.sender) == ("gossip", "r9")
    assert "'gossip'" in str(info.value) and m.PROTOCOL in str(info.value)
    # an unknown type in a broken envelope is just broken
    for data in (raw(sender="*", msg={"type": "gossip"}), raw(sender="r9", msg={"type": "g" * (m.MAX_NAME + 1)})):
        with pytest.raises(m.WireError) as info2:
            m.decode(data)
        assert not isinstance(info2.value, m.UnknownMessageType)


def test_another_major_is_refused_naming_both_versions() -> None:
    with pytest.raises(m.VersionRefused) as info:
        m.decode(raw(v=2, sender="r9", msg={"type": "whatever 2.0 sends", "x": [1]}, minor=3, release="1.4.0"))
    e = info.value
    assert (e.version, e.minor, e.release, e.sender, e.speaks) == (2, 3, "1.4.0", "r9", "2.3")
    text = str(e)
    assert "message is version 2.3" in text and "'r9'" in text and "ramps 1.4.0" in text
    assert f"this node speaks version {m.PROTOCOL} (ramps {ramps.__version__})" in text
    assert "malformed" not in text


@pytest.mark.parametrize("head", [
    {"v": 0}, {"v": 2, "sender": 7}, {"v": 2, "sender": "a*"}, {"v": 3, "minor": -1, "release": "x" * 999},
    {"v": 2, "release": "1.0\n; rm -rf /"}, {"v": 2**64 - 1, "sender": {"deep": [[[]]]}},
])
def test_what_another_major_says_of_itself_is_used_only_when_sane(head: dict) -> None:
    with pytest.raises(m.VersionRefused) as info:
        m.decode(msgspec.msgpack.encode({**head, "msg": None}))
    e = info.value
    assert e.version == head["v"] and f"message is version {head['v']}" in str(e)
    assert e.sender in ("", head.get("sender")) and "\n" not in str(e) and len(str(e)) < 600


def test_garbage_and_size_are_checked_as_before() -> None:
    with pytest.raises(m.WireError, match="exceeds the limit"):
        m.decode(raw(v=2) + b"\x00" * 200, max_bytes=100)  # size first, even for another version
    for data in (b"", b"\xc1", msgspec.msgpack.encode([1, 2]), msgspec.msgpack.encode({"v": "1"})):
        with pytest.raises(m.WireError) as info:
            m.decode(data)
        assert type(info.value) is m.WireError
    deep = b"\x91" * 100_000 + b"\xc0"
    for data in (b"\x82\xa1v\x01\xa4junk" + deep,  # an unknown field nested absurdly deep
                 b"\x83\xa1v\x01\xa6sender\xa1p\xa3msg\x82\xa4type\xa3ack\xa4junk" + deep):
        with pytest.raises(m.WireError, match="nested too deeply"):
            m.decode(data)


# ------------------------------------------------------------------ at a node
@pytest.fixture
def team():
    t = MemoryTeam({"r1": (2, 1.0), "r2": (2, 1.0)})
    t.run(3.0)
    yield t
    t.close()


def test_a_node_counts_refused_versions_and_unknown_types_apart_and_logs_each_once(team, caplog) -> None:
    r1 = team.nodes["r1"]
    other = team.bus.transport("r9")
    caplog.set_level(logging.WARNING, logger="ramps.node")
    for _ in range(3):
        other.put(keys.load_now(team.team, "r9"), raw(v=2, sender="r9", msg={"type": "load", "robot": "r9"}))
        other.put(keys.inbox(team.team, "r1"), raw(sender="r9", msg={"type": "gossip"}))
    other.put(keys.inbox(team.team, "r1"), b"garbage")
    team.run(2.0)
    assert (r1.version_refused, r1.unknown_types, r1.bad_messages) == (3, 3, 7)  # all dropped, 6 named
    lines = [r.getMessage() for r in caplog.records if r.name == "ramps.node" and "r9" in r.getMessage()
             and r.getMessage().startswith("node r1 ")]
    refused = [x for x in lines if "refuses" in x]
    assert len(refused) == 1, lines
    assert "message is version 2" in refused[0] and f"speaks version {m.PROTOCOL}" in refused[0]
    assert len([x for x in lines if "'gossip'" in x]) == 1
    # r9 never became a place for programs, and the team still works
    assert sorted(r1.node.view.candidates(r1._clock())) == ["r1", "r2"]
    assert r1.reports.last.bad_messages == 7  # `ramps status` "dropped msgs" counts them all
    assert not [r for r in caplog.records if "malformed" in r.getMessage() and "r9" in r.getMessage()]


def test_a_flood_of_invented_names_is_counted_not_logged_without_end(team, caplog) -> None:
    caplog.set_level(logging.WARNING, logger="ramps.node")
    other = team.bus.transport("x")
    for i in range(500):
        other.put(keys.inbox(team.team, "r1"), raw(v=2, sender=f"n{i}"))
    team.run(1.0)
    assert team.nodes["r1"].version_refused == 500
    assert sum("refuses" in r.getMessage() for r in caplog.records) <= 64
