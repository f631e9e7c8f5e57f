"""The ``ramps`` command as a package: every command and group answers
``--help``, whole on an 80-column terminal, its values named for what to type
(``--timeout SECONDS``, no typer ``<float range>``), and the testbed's fault
commands, generated from one table, take the arguments they document."""

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


#: typer's own placeholders for a value and its range notation, none of which ``--help`` may show
TYPER_PLACEHOLDERS = ("<list[", "<int range>", "<float range>", "<bool>", "<str>", "<path>", "<int>",
                      "<float>", "<=x", "x>=", "x<=")


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
                # a value is named (``--connect ENDPOINT``); a flag shows none
                long_name = max(param.opts, key=len)
                if param.is_flag:
                    assert not re.search(rf"(?<![\w-]){re.escape(long_name)} [A-Z<]", res.output), (p, long_name)
                else:
                    assert param.metavar and param.metavar.upper() == param.metavar, (p, long_name)
                    assert f"{long_name} {param.metavar}" in res.output, (p, long_name, res.output)
        for placeholder in TYPER_PLACEHOLDERS:
            assert placeholder not in res.output, (" ".join(["ramps", *p, "--help"]), placeholder, res.output)


def _help(*words: str) -> str:
    res = runner.invoke(app, [*words, "--help"], env={"COLUMNS": "80"}, terminal_width=80)
    assert res.exit_code == 0, res.output
    return " ".join(res.output.split())  # the help text as one line, unwrapped


def test_help_names_what_to_type_and_ranges_in_words():
    peers = _help("testbed", "experiment", "peers")
    for shown in ("-s, --scenario NAME", "--programs N", "--quota CORES", "--timeout SECONDS", "--keep-logs DIR",
                  "--out FILE", "[1 to 500]", "[default: 0.32; 0.05 to 4]", "[default: 1500.0; at least 10]"):
        assert shown in peers, (shown, peers)
    node = _help("node")
    for shown in ("-c, --connect ENDPOINT", "--config FILE", "--cores N", "--lease-ms MS", "--secure secured team"):
        assert shown in node, (shown, node)
    assert "--cores N cores offered to programs (default: detected) --speed" in node  # x>=1 says nothing new
    # an argument is named by its value alone, a name of its own overrides the table
    assert "Arguments: PROGRAM registered program name" in _help("submit")
    assert "Arguments: ROBOT robot, e.g. r3 [required] PROBABILITY drop probability" in _help("testbed", "lossy")
    assert "--loaded ROBOT[=N]" in _help("testbed", "up")
    assert "--loaded N" in _help("testbed", "experiment", "speeds")


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
