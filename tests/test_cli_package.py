"""The ``ramps`` command as a package: every command and group answers
``--help``, and the testbed's fault commands, generated from one table, take
the arguments they document."""

from __future__ import annotations

import typer
from typer.core import TyperArgument, TyperGroup, TyperOption
from typer.testing import CliRunner

from ramps.cli import app
from ramps.cli.testbed import FAULTS

runner = CliRunner()


def _paths(cmd: object, path: list[str]) -> list[list[str]]:
    found = [path]
    if isinstance(cmd, TyperGroup):
        for name, sub in cmd.commands.items():
            found += _paths(sub, path + [name])
    return found


def test_every_command_and_group_answers_help():
    paths = _paths(typer.main.get_command(app), [])
    names = {" ".join(p) for p in paths}
    # the groups and commands of the README are all there
    assert {"node", "submit", "status", "demo", "sim paper", "bench dispatch", "bench metrics", "testbed up",
            "testbed experiment faults", "team init", "report", "top", "ros", "version"} <= names
    for p in paths:
        res = runner.invoke(app, [*p, "--help"])
        assert res.exit_code == 0, (p, res.output)
        assert "Usage:" in res.output


def test_fault_commands_come_from_the_table_in_its_order():
    testbed = typer.main.get_command(app).commands["testbed"]
    assert isinstance(testbed, TyperGroup)
    names = list(testbed.commands)
    assert names[names.index("crash"):names.index("crash") + len(FAULTS)] == list(FAULTS)
    for kind, fault in FAULTS.items():
        cmd = testbed.commands[kind]
        assert cmd.help == fault.help
        args = [p.name for p in cmd.params if isinstance(p, TyperArgument)]
        assert args == ["robot", *(p.name for p in fault.extra)]
        assert [p.name for p in cmd.params if isinstance(p, TyperOption)] == ["tb"]


def test_lossy_checks_its_probability_before_touching_a_testbed():
    res = runner.invoke(app, ["testbed", "lossy", "r3", "2"])
    assert res.exit_code == 2
    assert "loss" in res.output


def test_the_fault_lines_read_as_before():
    class Bed:
        team = "tb-x"

    assert FAULTS["crash"].done("r3", None, Bed()) == "r3: crashed (SIGKILL)"
    assert FAULTS["recover"].done("r3", [], Bed()) == "r3: recovered (nothing to undo); alive in team tb-x"
    assert FAULTS["recover"].done("r3", ["link up"], Bed()) == "r3: recovered (link up); alive in team tb-x"
    assert FAULTS["lossy"].done("r3", None, Bed(), 0.25) == "r3: 25% packet loss"
    assert FAULTS["lossy"].done("r3", None, Bed(), 0.0) == "r3: loss removed"
