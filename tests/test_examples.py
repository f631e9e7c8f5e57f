"""The runnable examples in examples/ do what their docstrings say: writing a
program (replan.py), submitting and mapping with the Team API
(submit_and_map.py: its calls and program run here; on a real team, slow),
and testing your own code with FakeTeam (fake_team_test.py)."""

from __future__ import annotations

import doctest
import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import pytest

from ramps.errors import BadArguments
from ramps.runtime.registry import default_registry, encode_args

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"


@pytest.fixture
def examples(monkeypatch) -> dict[str, ModuleType]:
    """The example modules, imported as their users would (examples/ on sys.path);
    the program they register is taken out of this process's registry afterwards."""
    monkeypatch.syspath_prepend(str(EXAMPLES))
    mods = {}
    for name in ("replan", "submit_and_map", "fake_team_test"):
        spec = importlib.util.spec_from_file_location(name, EXAMPLES / f"{name}.py")
        assert spec is not None and spec.loader is not None
        mods[name] = importlib.util.module_from_spec(spec)
        monkeypatch.setitem(sys.modules, name, mods[name])
        spec.loader.exec_module(mods[name])
    yield mods
    default_registry._specs.pop("shortest_path", None)


def test_the_program_is_registered_and_its_arguments_checked_before_sending(examples):
    replan = examples["replan"]
    spec = default_registry.get("shortest_path")
    assert spec.target == "replan:shortest_path" and spec.work == 0.5
    assert encode_args(spec, {"grid": ["."], "start": [0, 0], "goal": [0, 0]})
    with pytest.raises(BadArguments, match="shortest_path"):
        encode_args(spec, {"grid": ["."], "start": [0, 0]})  # goal missing: refused at the caller
    assert doctest.testmod(replan).failed == 0
    with pytest.raises(ValueError, match="not a free cell"):
        replan.shortest_path(grid=["#."], start=[0, 0], goal=[0, 1])
    assert replan.shortest_path(grid=[".#."], start=[0, 0], goal=[0, 2]) == {"length": None, "path": []}


def test_the_routes_the_team_api_example_submits_are_valid_calls(examples):
    sam, replan = examples["submit_and_map"], examples["replan"]
    spec = default_registry.get("shortest_path")
    for call in sam.calls(8):
        encode_args(spec, call)
        route = replan.shortest_path(**call)
        assert route["length"] is not None and route["path"][0] == call["start"] and route["path"][-1] == call["goal"]
        assert all(abs(a[0] - b[0]) + abs(a[1] - b[1]) == 1 for a, b in zip(route["path"], route["path"][1:]))


def test_the_fake_team_example_passes(examples):
    mod = examples["fake_team_test"]
    tests = [getattr(mod, n) for n in dir(mod) if n.startswith("test_")]
    assert len(tests) == 2
    for t in tests:
        t()


@pytest.mark.slow
def test_the_team_api_example_on_a_local_team(examples, capsys):
    assert examples["submit_and_map"].main(["--local", "2", "-n", "4"]) == 0
    out = capsys.readouterr().out
    assert "one route: 13 steps, computed on r" in out and "4 more routes" in out
