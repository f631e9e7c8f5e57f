"""A load report's listed origins: one regex over the joined names refuses
exactly what RobotName's pattern refuses name by name, and ``decode`` takes
and refuses exactly what the full schema does, with the same errors.

How this works: ``decode`` parses an envelope once with a schema whose
``RunningProgram.origin`` has no pattern, then checks every listed origin at
once (``KEY_UNSAFE`` over the names joined); bytes it refuses are read again
against the full schema (``_checked_decoder``) to say why. Here hypothesis
draws names (any text, and adversarial ones made of the refused characters
and their neighbours) and whole reports, and compares the new check and
``decode`` with the old ones: msgspec's pattern per name, and the old decode
(head, then the full schema) written out below.
"""

from __future__ import annotations

import re

import msgspec
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ramps.core import messages as m
from ramps.core.wirebase import DECODE_ERRORS, head_decoder, refused, why
from ramps.core.wirelimits import _KEY_SAFE, KEY_UNSAFE, RobotName

_SETTINGS = settings(max_examples=400, derandomize=True, database=None, deadline=None,
                     suppress_health_check=[HealthCheck.too_slow])
_pattern = re.compile(_KEY_SAFE)
_robot_name = msgspec.msgpack.Decoder(RobotName)
#: the refused characters, their neighbours, and other characters that trip regexes up
_EDGE = "*$?#\x00\x01\x1e\x1f\x20\x7e\x7f\x80\n\r\t\\]^-[/.\u2028\u0085\ufeff\U0001f916"
names = st.text(st.sampled_from(_EDGE) | st.characters(blacklist_categories=("Cs",)), max_size=12) | st.text(_EDGE, max_size=6)


def _old_accepts(name: str) -> bool:
    """What msgspec's RobotName says of one name (its pattern and length)."""
    try:
        _robot_name.decode(msgspec.msgpack.encode(name))
    except msgspec.ValidationError:
        return False
    return True


def test_the_pattern_is_the_one_the_wire_always_had() -> None:
    # error texts quote it: it must not change by a byte
    assert _KEY_SAFE == "\\A[^*$?#\\x00-\\x1f\\x7f]*\\Z"
    assert msgspec.structs.fields(m._CheckedRunningProgram)[1].type == RobotName


@_SETTINGS
@given(names)
def test_one_name_the_joined_check_and_the_pattern_agree(name: str) -> None:
    new = KEY_UNSAFE.search(name) is None
    assert new == (_pattern.search(name) is not None)
    if 1 <= len(name) <= m.MAX_NAME:
        assert new == _old_accepts(name)


@_SETTINGS
@given(st.lists(names.filter(lambda n: 1 <= len(n) <= m.MAX_NAME), max_size=20))
def test_a_list_of_names_the_joined_check_and_every_pattern_agree(listed: list[str]) -> None:
    assert (KEY_UNSAFE.search("".join(listed)) is None) == all(_old_accepts(n) for n in listed)


def _old_decode(data: bytes) -> m.Envelope | msgspec.Struct:
    """decode as it was: the head, then the body against the full schema."""
    if len(data) > m.MAX_MESSAGE_BYTES:
        raise m.WireError("too big")
    try:
        head = head_decoder.decode(data)
    except DECODE_ERRORS as exc:
        raise m.WireError(f"not a ramps message: {why(exc)}") from exc
    if head.v != m.PROTOCOL_MAJOR:
        raise refused(head)
    try:
        return m._checked_decoder.decode(data)
    except DECODE_ERRORS as exc:
        if isinstance(exc, msgspec.ValidationError):
            if m._CONSTRAINT.match(str(exc)):
                raise m.WireError(f"ramps message field out of bounds: {exc}") from exc
            unknown = m._unknown_type(data)
            if unknown is not None:
                raise unknown from exc
        raise m.WireError(f"malformed ramps message: {why(exc)}") from exc


def _outcome(decoder, data: bytes) -> tuple[str, object]:
    try:
        env = decoder(data)
    except m.WireError as exc:
        return type(exc).__name__, str(exc)
    return "ok", msgspec.to_builtins(env)


def _report(running: list[m.RunningProgram], **changes: object) -> m.LoadReport:
    rep = m.LoadReport(robot="r1", incarnation=1, seq=1, cores=2, speed=1.0, cpu_busy=0.0, runnable=0.0,
                       ramps_running=len(running), ramps_avg=0.0, accepted_total=0, finished_total=0,
                       running=running)
    return msgspec.structs.replace(rep, **changes)


running = st.lists(st.builds(m.RunningProgram, names, names, st.none() | st.floats(-0.5, 1.5)), max_size=6)


@_SETTINGS
@given(running, st.sampled_from([{}, {"cores": 0}, {"robot": "*"}, {"remaining": [-1.0]}, {"seq": -1}]),
       st.sampled_from([m.PROTOCOL_MAJOR, m.PROTOCOL_MAJOR + 1]), names)
def test_decode_takes_and_refuses_what_the_full_schema_does_with_the_same_error(
        listed: list[m.RunningProgram], changes: dict[str, object], v: int, sender: str) -> None:
    rep = _report(listed, **changes)
    data = msgspec.msgpack.encode({"v": v, "sender": sender, "msg": msgspec.to_builtins(rep)})
    assert _outcome(m.decode, data) == _outcome(_old_decode, data)


@_SETTINGS
@given(st.binary(max_size=64) | running.map(lambda r: m.encode("r1", _report(r))).flatmap(
    lambda b: st.integers(0, len(b)).map(lambda i: b[:i] + b"\xc1" + b[i + 1:])))
def test_decode_of_garbage_and_broken_reports_says_what_it_said(data: bytes) -> None:
    assert _outcome(m.decode, data) == _outcome(_old_decode, data)


@pytest.mark.parametrize("bad", ["*", "a#b", "x\x00", "\x7f", "r$", "?"])
def test_a_bad_origin_anywhere_in_the_list_is_named_where_it_is(bad: str) -> None:
    listed = [m.RunningProgram("p", "r2")] * 5 + [m.RunningProgram("p", bad)] + [m.RunningProgram("p", "r3")]
    with pytest.raises(m.WireError, match=re.escape("$.msg.running[5][1]")):
        m.decode(m.encode("r1", _report(listed)))
