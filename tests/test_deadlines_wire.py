"""Deadlines at the edges: the wire refuses deadline fields out of their
limits, the caller and the core refuse a deadline that is not a finite
number (``ValueError``), and what protocol 1.1 adds is written where a
developer looks for it (``PROTOCOL_MINOR``'s comment, the wire table)."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import msgspec
import pytest

from ramps.core import messages as m
from ramps.core.events import Submit
from ramps.testing import FakeTeam
from ramps.testing.hostile import BAD_DEADLINES, GOOD_DEADLINES, ME

from test_wire_golden import PREVIOUS, _old_wire

ROOT = Path(__file__).resolve().parents[1]


def _with(field: str, value) -> bytes:
    if field == "deadline_in":
        msg: m.Message = m.OffloadRequest(program_id="a", attempt=1, origin="p", host=ME, program="noop",
                                          deadline_in=1.0)
    elif field == "missed_deadline":
        msg = m.ProgramOutcome(request_id=1, ok=True, missed_deadline=True)
    else:
        msg = m.SubmitProgram(client="p", request_id=1, program="noop", deadline=1.0, on_miss="fail")
    d = msgspec.to_builtins(m.Envelope(v=m.PROTOCOL_VERSION, sender="p", msg=msg), builtin_types=(bytes,))
    d["msg"][field] = value
    return msgspec.msgpack.encode(d)


@pytest.mark.parametrize("field", ["deadline_in", "deadline"])
@pytest.mark.parametrize("value", [float("nan"), float("inf"), float("-inf"), -1.0, -1e-300, "2", True, [], 2**64 - 1])
def test_the_wire_refuses_a_deadline_that_is_not_a_finite_number_of_seconds(field: str, value) -> None:
    data = _with(field, value)
    if value == 2**64 - 1:  # an integer is a number: it decodes as the float it is
        assert getattr(m.decode(data).msg, field) == float(value)
        return
    with pytest.raises(m.WireError, match=field):
        m.decode(data)


@pytest.mark.parametrize("field, value", [("on_miss", "x" * (m.MAX_NAME + 1)), ("on_miss", 3),
                                          ("missed_deadline", 1), ("missed_deadline", "yes")])
def test_the_wire_refuses_on_miss_and_missed_deadline_of_the_wrong_kind(field: str, value) -> None:
    with pytest.raises(m.WireError, match=field):
        m.decode(_with(field, value))


@pytest.mark.parametrize("value", [0.0, 1e-300, 1e300, sys.float_info.max])
def test_the_largest_finite_deadlines_decode_and_a_node_takes_them(value: float) -> None:
    assert m.decode(_with("deadline", value)).msg.deadline == value
    assert m.decode(_with("deadline_in", value)).msg.deadline_in == value
    team = FakeTeam({"o": (2, 1.0)})
    team.now = 100.0  # the node makes a client's deadline absolute: now + deadline stays finite
    team.handle("o", Submit(program_id="p", program="x", work=1.0, deadline=team.now + value))
    assert "p" in team.nodes["o"].origin.programs


@pytest.mark.parametrize("deadline", BAD_DEADLINES)
def test_the_core_refuses_a_deadline_that_is_not_a_finite_number(deadline) -> None:
    team = FakeTeam({"o": (2, 1.0)})
    with pytest.raises(ValueError, match="a deadline must be a finite number"):
        team.handle("o", Submit(program_id="p", program="x", work=1.0, deadline=deadline))
    assert not team.nodes["o"].origin.programs and not team.log


@pytest.mark.parametrize("deadline", [d for d in GOOD_DEADLINES if d is not None])
def test_the_core_takes_any_finite_absolute_deadline(deadline) -> None:
    team = FakeTeam({"o": (2, 1.0)})
    team.handle("o", Submit(program_id="p", program="x", work=1.0, deadline=deadline, on_miss="fail"))
    assert "p" in team.nodes["o"].origin.programs


@pytest.mark.parametrize("bad", [True, False, 10**400, -(10**400), float("nan"), float("inf"), -1.0, 0, "2", b"2"])
def test_the_caller_gets_a_value_error_for_a_deadline_that_is_not_seconds(bad) -> None:
    from ramps.runtime.client import Team

    team = Team.__new__(Team)  # options() checks its arguments before it looks at the team
    with pytest.raises(ValueError, match="deadline is seconds from submission"):
        team.options(deadline=bad)


def _added_since_previous() -> list[tuple[str, str]]:
    old = _old_wire(PREVIOUS)
    added = []
    for name in dir(m):
        cls = getattr(m, name)
        if isinstance(cls, type) and issubclass(cls, msgspec.Struct) and hasattr(old, name):
            added += [(name, f) for f in cls.__struct_fields__ if f not in getattr(old, name).__struct_fields__]
    return sorted(added)


def test_protocol_minor_says_what_it_adds_as_the_wire_table_does() -> None:
    added = _added_since_previous()
    assert ("SubmitProgram", "deadline") in added and ("ProgramResult", "worker_died") in added
    source = (ROOT / "src/ramps/core/wirebase.py").read_text()
    comment = source[source.index("#: the protocol this code speaks"):source.index("PROTOCOL_MAJOR =")]
    table = (ROOT / "docs/wire-compatibility.md").read_text()
    [row] = [line for line in table.splitlines() if line.startswith("| 0.2.0 | 1.1 |")]
    for struct, field in added:
        assert f"``{struct}.{field}``" in comment, f"PROTOCOL_MINOR's comment does not name {struct}.{field}"
        assert re.search(rf"`({struct}\.)?{field}`", row), f"the wire table's 0.2.0 row does not name {field}"
