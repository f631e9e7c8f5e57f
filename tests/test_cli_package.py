"""The ``ramps`` command as a package: every command and group answers
``--help``, whole on an 80-column terminal, and the testbed's fault commands,
generated from one table, take the arguments they document."""

from __future__ import annotations

import re

import typer
from typer.core import TyperArgument, TyperGroup, TyperOption
from typer.testing import CliRunner

from ramps.cli import app
from ramps.cli.testbed import FAULTS

runner = CliRunner()


def _commands(cmd: object, path: list[str]) -> list[tuple[list[str], object]]:
    found = [(path, cmd)]
    if isinstance(cmd, TyperGroup):
        for name, sub in cmd.commands.items():
            found += _commands(sub, path + [name])
    return found


#: an option name as a whole token: what is left of a name cut to fit
#: (``--diagnostics-pe…``) is another token
OPTION_NAME = re.compile(r"(?<![\w-])-{1,2}[\w-]+(?![\w-])")


def _listed_options(help_text: str) -> set[str]:
    """The option names on the lines that list the options: those that start
    with an option name (in click's layout or in a rich panel)."""
    listed: set[str] = set()
    for line in help_text.splitlines():
        first = line.strip(" │*").split(maxsplit=1)
        if first and first[0].startswith("-"):
            listed.update(OPTION_NAME.findall(line))
    return listed


def test_every_command_and_group_answers_help_whole_at_80_columns():
    commands = _commands(typer.main.get_command(app), [])
    names = {" ".join(p) for p, _ in commands}
    # the groups and commands of the README are all there
    assert {"node", "submit", "status", "demo", "sim paper", "bench dispatch", "bench metrics", "testbed up",
            "testbed experiment faults", "team init", "report", "top", "ros", "version"} <= names
    for p, cmd in commands:
        res = runner.invoke(app, [*p, "--help"], env={"COLUMNS": "80"}, terminal_width=80)
        assert res.exit_code == 0, (p, res.output)
        assert "Usage:" in res.output
        assert max(map(len, res.output.splitlines())) <= 80, (p, res.output)
        listed = _listed_options(res.output)
        for param in cmd.params:  # type: ignore[attr-defined]
            if isinstance(param, TyperOption) and not param.hidden:
                for name in (*param.opts, *param.secondary_opts):
                    assert name in listed, (" ".join(["ramps", *p, "--help"]), name, res.output)


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
