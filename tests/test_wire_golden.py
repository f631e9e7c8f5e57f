"""Every message of the previous release decodes today, and what today sends
decodes under the previous release's rules.

How this works: ``tests/golden/<release>/`` holds one full and one minimal
sample of every message type as that release's own encoder wrote them
(``tests/golden/make_samples.py``, run against the release's tag), with their
fields in ``manifest.json``. Today's decoder must read every sample, give
every field the release set the same value, and leave every field added
since at its default. ``tests/golden/0.1.0/messages.py`` is release 0.1.0's
wire module itself (strict: exact version, no unknown field), kept so the
other direction is checked with the previous release's real decoder: each
sample decoded and re-encoded today must decode there to what 0.1.0's own
bytes gave, and so must a thousand random honest messages of today (fields
added since at their defaults). docs/wire-compatibility.md is the policy
these enforce.
"""

from __future__ import annotations

import importlib.util
import json
import sys
import typing
from pathlib import Path

import msgspec
import pytest

from ramps.core import messages as m

GOLDEN = Path(__file__).resolve().parent / "golden"
PREVIOUS = "0.1.0"


def _manifest(release: str) -> dict:
    return json.loads((GOLDEN / release / "manifest.json").read_text())


def _old_wire(release: str):
    """Release ``release``'s own wire module, loaded under a name of its own."""
    name = "ramps_wire_" + release.replace(".", "_")
    if name not in sys.modules:
        spec = importlib.util.spec_from_file_location(name, GOLDEN / release / "messages.py")
        assert spec is not None and spec.loader is not None
        mod = importlib.util.module_from_spec(spec)
        sys.modules[name] = mod
        spec.loader.exec_module(mod)
    return sys.modules[name]


MANIFEST = _manifest(PREVIOUS)
NAMES = sorted(MANIFEST["samples"])


def _plain(x):
    """A message as JSON builtins with every field, defaults included (as
    ``manifest.json`` has them; today's encoders leave defaults out)."""
    if isinstance(x, msgspec.Struct):
        cfg = x.__struct_config__
        values = [_plain(getattr(x, f)) for f in x.__struct_fields__]
        if cfg.array_like:
            return values
        d = dict(zip(x.__struct_fields__, values))
        if cfg.tag_field is not None:
            d[cfg.tag_field] = cfg.tag
        return d
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    return json.loads(msgspec.json.encode(x))


_fields = _plain


def _known(now, then):
    """``now`` (``_plain``) less what ``then`` does not have, in nested
    records too (a ``LoadReport`` in an ``OffloadRejected``): the fields
    the release that wrote ``then`` knows."""
    if isinstance(now, dict) and isinstance(then, dict):
        return {k: _known(v, then[k]) for k, v in now.items() if k in then}
    if isinstance(now, list) and isinstance(then, list) and len(now) == len(then):
        return [_known(a, b) for a, b in zip(now, then)]
    return now


def test_the_previous_release_is_what_its_samples_say() -> None:
    assert (MANIFEST["release"], MANIFEST["protocol"]) == (PREVIOUS, "1.0")
    assert (m.PROTOCOL_MAJOR, m.PROTOCOL) == (1, "1.1")  # a minor above it: the same team
    old = _old_wire(PREVIOUS)
    assert old.PROTOCOL_VERSION == m.PROTOCOL_MAJOR
    # no message type was removed or renamed since, and each is sampled full and minimal
    old_types = {t.__struct_config__.tag for t in typing.get_args(old.Message)}
    assert old_types <= m.KNOWN_TYPES
    assert {n.rsplit("-", 1)[0] for n in NAMES} == old_types and len(NAMES) == 2 * len(old_types)


@pytest.mark.parametrize("name", NAMES)
def test_every_sample_of_the_previous_release_decodes_today(name: str) -> None:
    data = (GOLDEN / PREVIOUS / f"{name}.msgpack").read_bytes()
    env = m.decode(data)
    assert env.sender == MANIFEST["sender"] and env.v == m.PROTOCOL_MAJOR
    then = MANIFEST["samples"][name]
    assert type(env.msg).__name__ == then["type"]
    now = _fields(env.msg)
    for key, value in then["fields"].items():
        got = _known(now.get(key), value)
        assert got == value, f"{name}: field {key} was {value!r} in {PREVIOUS}, decodes as {got!r}"
    # fields added since the release are at their defaults (encode leaves them out)
    added = set(now) - set(then["fields"])
    assert _fields(type(env.msg)(**{k: getattr(env.msg, k) for k in env.msg.__struct_fields__
                                    if k not in added})) == now


@pytest.mark.parametrize("name", NAMES)
def test_what_today_sends_decodes_under_the_previous_release(name: str) -> None:
    old = _old_wire(PREVIOUS)
    data = (GOLDEN / PREVIOUS / f"{name}.msgpack").read_bytes()
    today = m.encode(MANIFEST["sender"], m.decode(data).msg)
    assert old.decode(today) == old.decode(data)  # 0.1.0's strict decoder: no field it does not know
    if name.endswith("-full"):
        # every field set: today's bytes are 0.1.0's, key for key and value for value (new fields stay
        # out at their defaults); only a map's header may be wider, where a message now has over 15 fields
        assert _same_maps(today, data)


def test_today_leaves_defaults_out_so_the_previous_release_fills_them_in() -> None:
    old = _old_wire(PREVIOUS)
    msg = m.OffloadRequest(program_id="p", attempt=1, origin="o", host="h", program="x")
    body = msgspec.msgpack.decode(m.encode("o", msg))["msg"]
    assert sorted(body) == ["attempt", "host", "origin", "program", "program_id", "type"]
    then = _plain(old.decode(m.encode("o", msg)).msg)
    assert then == {k: v for k, v in _plain(msg).items() if k in then}
    assert set(_plain(msg)) - set(then) == {"deadline_in", "accelerator"}  # added since, at their defaults


def test_the_previous_release_refuses_a_field_it_does_not_know() -> None:
    """Why new fields must stay at their defaults while a team may hold a
    0.1.0 node: it drops the whole message (the policy's one exception)."""
    old = _old_wire(PREVIOUS)
    raw = msgspec.msgpack.encode({"v": 1, "sender": "a", "msg": {"type": "ack", "program_id": "p", "attempt": 1,
                                                                 "origin": "o", "since_1_1": 1}})
    with pytest.raises(old.WireError, match="since_1_1"):
        old.decode(raw)
    assert m.decode(raw).msg == m.ResultAck(program_id="p", attempt=1, origin="o")


def _same_maps(a: bytes, b: bytes) -> bool:
    """Two msgpack messages with the same keys in the same order and the same
    values (msgspec writes a struct of more than 15 fields with a 3-byte map
    header even when it leaves fields out, so the bytes may differ there)."""
    x, y = msgspec.msgpack.decode(a), msgspec.msgpack.decode(b)

    def order(v):
        return [(k, order(w)) for k, w in v.items()] if isinstance(v, dict) else v
    return order(x) == order(y)


def _as_previous(old, msg):
    """``msg`` with every field added since the previous release at its default."""
    known = getattr(old, type(msg).__name__).__struct_fields__
    kept = {}
    for f in msgspec.structs.fields(msg):
        if f.name in known:
            value = getattr(msg, f.name)
            nested = isinstance(value, msgspec.Struct) and hasattr(old, type(value).__name__)
            kept[f.name] = _as_previous(old, value) if nested else value
        else:
            assert f.required is False, f"{type(msg).__name__}.{f.name}: added since {PREVIOUS} without a default"
    return type(msg)(**kept)


@pytest.mark.parametrize("seed", range(4))
def test_random_honest_messages_of_today_decode_under_the_previous_release(seed: int) -> None:
    """What honest nodes send (``ramps.testing.hostile.random_message``:
    every type, values across each field's limits), fields added since at
    their defaults: 0.1.0 reads each with the same values. A limit relaxed
    on the sending side, or a default changed, fails here."""
    import random

    from ramps.testing import hostile

    old = _old_wire(PREVIOUS)
    rng = random.Random(seed)
    for _ in range(250):
        msg = hostile.random_message(rng)
        sender = rng.choice(hostile.PEERS)
        if not hasattr(old, type(msg).__name__):  # a type added since: the previous release skips it
            with pytest.raises(old.WireError):
                old.decode(m.encode(sender, msg))
            continue
        msg = _as_previous(old, msg)
        data = m.encode(sender, msg)
        try:
            m.decode(data)
        except m.WireError:
            continue  # the generator's extremes go past a limit now and then: refused today as well
        env = old.decode(data)
        then = _plain(env.msg)  # the fields the previous release knows (those added since are at their defaults)
        assert env.sender == sender and then == _known(_plain(msg), then), msg


@pytest.mark.parametrize("name", ["offload-full", "offload-minimal", "submit-full", "submit-minimal",
                                  "outcome-full", "outcome-minimal"])
def test_messages_without_a_deadline_are_what_the_previous_release_sent(name: str) -> None:
    """Deadlines (protocol 1.1) add ``OffloadRequest.deadline_in``,
    ``SubmitProgram.deadline`` and ``on_miss``, ``ProgramOutcome.missed_deadline``:
    a message that sets none of them is the previous release's, byte for
    byte where that release wrote every field, and its decoder reads it."""
    old = _old_wire(PREVIOUS)
    data = (GOLDEN / PREVIOUS / f"{name}.msgpack").read_bytes()
    msg = m.decode(data).msg
    new = {"deadline_in", "deadline", "on_miss", "missed_deadline"} & set(msg.__struct_fields__)
    assert new and all(getattr(msg, f) == msgspec.structs.fields(msg)[msg.__struct_fields__.index(f)].default
                       for f in new)
    today = m.encode(MANIFEST["sender"], msg)
    assert not new & set(msgspec.msgpack.decode(today)["msg"])  # left out at their defaults
    if name.endswith("-full"):
        assert _same_maps(today, data)
    assert old.decode(today) == old.decode(data)


def test_a_deadline_crosses_today_and_only_today() -> None:
    """With a deadline set the field is on the wire: today's nodes read it;
    0.1.0 drops the message (as for every new field it does not know), which
    is why an origin sends ``deadline_in`` only to hosts in time."""
    old = _old_wire(PREVIOUS)
    msg = m.OffloadRequest(program_id="p", attempt=1, origin="o", host="h", program="x", deadline_in=1.5)
    data = m.encode("o", msg)
    assert m.decode(data).msg.deadline_in == 1.5
    with pytest.raises(old.WireError, match="deadline_in"):
        old.decode(data)
    sub = m.SubmitProgram(client="c", request_id=1, program="x", deadline=2.0, on_miss="fail")
    assert m.decode(m.encode("c", sub)).msg == sub
    with pytest.raises(m.WireError):
        m.decode(m.encode("c", m.SubmitProgram(client="c", request_id=1, program="x", deadline=-1.0)))
