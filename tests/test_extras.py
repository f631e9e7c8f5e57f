"""The base install (``pip install ramps-robotics``) runs a node, a client
and the simulator; OR-Tools (``route``) and matplotlib (``plots``) are
extras, and what needs one says which to install in one line."""

from __future__ import annotations

import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
from typer.testing import CliRunner

import ramps.extras
from ramps.cli import app
from ramps.errors import ConfigError
from ramps.extras import MissingExtra, require

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture
def without(monkeypatch):
    """Make the named top-level modules look uninstalled to ``ramps.extras``."""
    def hide(*modules: str) -> None:
        real = ramps.extras.missing
        monkeypatch.setattr(ramps.extras, "missing", lambda m: m in modules or real(m))
    return hide


def test_a_missing_extra_is_one_line_naming_it():
    require("msgspec", "anything")  # installed: nothing happens
    with pytest.raises(MissingExtra) as info:
        require("ramps_no_such_module", "route_plan", "route")
    assert str(info.value) == ("route_plan needs ramps_no_such_module, which is not installed here: "
                               "pip install 'ramps-robotics[route]'")
    assert isinstance(info.value, ConfigError) and isinstance(info.value, ModuleNotFoundError)


def test_route_plan_without_ortools_says_which_extra(without):
    from ramps.programs.route import plan_route

    without("ortools")
    with pytest.raises(MissingExtra, match=r"route_plan needs ortools.*ramps-robotics\[route\]"):
        plan_route(picks=6)


@pytest.mark.parametrize("argv, extra", [(["report", "no-such-trace.jsonl"], "plots"), (["demo"], "demo")])
def test_commands_without_their_extra_fail_in_one_line(without, argv, extra):
    without("ortools", "matplotlib")
    res = CliRunner().invoke(app, argv)
    assert res.exit_code == 2, res.output
    assert f"pip install 'ramps-robotics[{extra}]'" in res.output
    assert "Traceback" not in res.output


def test_the_base_install_leaves_out_ortools_and_matplotlib_and_the_demo_extra_has_both():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    base = " ".join(project["dependencies"])
    assert "ortools" not in base and "matplotlib" not in base
    extras = project["optional-dependencies"]
    assert any(d.startswith("ortools") for d in extras["route"])
    assert any(d.startswith("matplotlib") for d in extras["plots"])
    assert {d.split(">")[0] for d in extras["demo"]} == {"ortools", "matplotlib"}
    assert set(ramps.extras.EXTRA_OF.values()) <= set(extras)


BLOCKED = ("ortools", "matplotlib", "numpy", "pandas")
SLIM = f"""
import importlib.abc, sys

class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in {BLOCKED!r}:
            raise ModuleNotFoundError(f"No module named {{name!r}}", name=name)

sys.meta_path.insert(0, Block())
import ramps.cli, ramps.runtime.node, ramps.runtime.client, ramps.testing
from ramps.runtime.forkserver import preload
from ramps.runtime.registry import BUILTINS
from ramps.sim.engine import simulate
from ramps.sim.scenario import ProgramSpec, RobotSpec, Scenario

res = simulate(Scenario(name="slim", robots=[RobotSpec(name="r1"), RobotSpec(name="r2")], seed=1,
                        programs=[ProgramSpec(origin="r1", count=4, work=5.0)]))
assert sum(res.distribution.values()) == 4, res.distribution
assert preload({{n: s.target for n, s in BUILTINS.items()}}) == []  # route_plan's OR-Tools: skipped
from ramps.extras import MissingExtra
from ramps.programs.route import plan_route
try:
    plan_route(picks=6)
except MissingExtra as exc:
    print("route_plan:", exc)
print("heavy:", sorted(m for m in sys.modules if m.split(".")[0] in {BLOCKED!r}))
"""


@pytest.mark.slow
def test_node_client_and_simulator_import_and_run_without_the_extras():
    """In a process where OR-Tools, matplotlib, numpy and pandas cannot be
    imported: the CLI, node, client and testing modules import, a simulation
    runs, the fork server's preload skips route_plan's OR-Tools, and
    route_plan fails in one line naming the extra."""
    out = subprocess.run([sys.executable, "-c", SLIM], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert "route_plan: route_plan needs ortools" in out.stdout and "ramps-robotics[route]" in out.stdout
    assert "heavy: []" in out.stdout


def _bootstrap(target: str, tmp_path: Path) -> list[str]:
    """The commands ``make TARGET`` runs from a fresh clone (no venv yet), as ``make -n`` prints them."""
    out = subprocess.run(["make", "-n", "-C", str(ROOT), target, f"VENV={tmp_path / 'venv'}"],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    return [ln for ln in out.stdout.splitlines() if "pip" in ln or "ramps" in ln]


@pytest.mark.skipif(subprocess.run(["which", "make"], capture_output=True).returncode != 0, reason="no make")
def test_make_demo_installs_the_demo_extra_alone_and_make_test_everything(tmp_path):
    """``make demo`` on a fresh clone installs ramps with its ``demo`` extra and
    nothing else (no test or check tools, no ROS 2, no action built);
    ``make test`` installs every extra it tests and builds the ROS action."""
    demo = _bootstrap("demo", tmp_path)
    installs = [ln for ln in demo if "pip install" in ln]
    assert installs and all("-e '.[demo]'" in ln for ln in installs), demo
    assert not any("--build-interfaces" in ln for ln in demo), demo
    assert demo[-1].endswith("ramps demo"), demo
    test = " ".join(_bootstrap("test", tmp_path))
    assert "-e '.[demo,test,check,ros]'" in test and "ramps ros --build-interfaces" in test, test
