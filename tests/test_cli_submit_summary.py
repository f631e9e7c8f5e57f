"""``ramps submit`` says how its programs ended and where they ran: the real
command (typer's CliRunner) with its client on an in-memory team
(``ramps.testing.memory``), in milliseconds."""

from __future__ import annotations

import json
import sys

import pytest
from typer.testing import CliRunner

from ramps.cli import app
from ramps.testing.memory import MemoryTeam

runner = CliRunner()


class _Driven:
    """The client ``ramps submit`` gets, on a memory team that runs each
    submitted program to its end (the command blocks on the result)."""

    def __init__(self, mem: MemoryTeam, robot: str, work: float) -> None:
        self.mem, self.client, self.work = mem, mem.connect(robot), work
        self.robot = self.client.robot

    def options(self, **opts):
        driven = self

        class _Opts:
            def submit(self, program, **kwargs):
                fut = driven.client.options(**opts, work=driven.work).submit(program, **kwargs)
                driven.mem.run(30.0, until=fut.done)
                return fut

        return _Opts()

    def close(self) -> None:
        self.client.close()


@pytest.fixture
def submit(monkeypatch):
    mem = MemoryTeam({"r1": (1, 1.0), "r2": (4, 4.0)}, programs=["e2eprogs:fail"])
    mem.run(3.0)

    def run(*args: str, work: float = 20.0):
        cli_node = sys.modules["ramps.cli.node"]  # the module (ramps.cli.node is also the command's name)
        monkeypatch.setattr(cli_node, "_connect_team", lambda *a, **k: _Driven(mem, "r1", work))
        return runner.invoke(app, ["submit", *args], env={"COLUMNS": "400"})

    yield run
    mem.close()


def test_a_failed_program_is_said_to_have_failed_where_it_ran(submit):
    res = submit("fail")  # heavy for the slow origin r1: it runs on r2, and raises
    assert res.exit_code == 1, res.output
    assert "no route to the dock" in res.output
    last = res.output.strip().splitlines()[-1]
    assert last.startswith("1 program(s) in ") and last.endswith(" s, origin r1: 1 failed on r2"), last


def test_done_programs_name_their_hosts_and_the_origin(submit):
    res = submit("echo", "--arg", "x=3", "--count", "2")
    assert res.exit_code == 0, res.output
    last = res.output.strip().splitlines()[-1]
    assert last.endswith(" s, origin r1: 2 done on r2 (2)"), last


def test_a_program_run_on_its_origin_says_so(submit):
    res = submit("echo", "--arg", "x=1", work=0.01)
    assert res.exit_code == 0, res.output
    assert res.output.strip().splitlines()[-1].endswith(" s, origin r1: 1 done on r1")


def test_json_lines_say_state_host_and_attempts(submit):
    res = submit("fail", "--json")
    assert res.exit_code == 1
    [line] = [json.loads(ln) for ln in res.stdout.splitlines() if ln.startswith("{")]
    assert line["ok"] is False and "no route to the dock" in line["error"]
    assert (line["state"], line["host"], line["attempts"]) == ("failed", "r2", 1)


def bracketed(grid: list[str]) -> str:
    """A program whose result and errors hold square brackets (Python types, indexes)."""
    if not grid:
        raise ValueError("no route: grid[0] is missing, want list[str]")
    return "[bold]route[/bold] via bay[2]"


def test_brackets_in_results_and_errors_are_printed_as_they_are(monkeypatch):
    """Results and errors are text, not console markup: a type the node names
    (``list[str]``), an index (``grid[0]``) and markup-like words come out whole."""
    mem = MemoryTeam({"r1": (1, 1.0), "r2": (4, 4.0)}, programs=["test_cli_submit_summary:bracketed"])
    mem.run(3.0)
    cli_node = sys.modules["ramps.cli.node"]
    monkeypatch.setattr(cli_node, "_connect_team", lambda *a, **k: _Driven(mem, "r1", 0.01))
    try:
        # the client lacks the program, so its node checks the arguments: a wrong type
        res = runner.invoke(app, ["submit", "bracketed", "--arg", 'grid="x"'], env={"COLUMNS": "400"})
        assert res.exit_code == 2, res.output  # refused for its arguments, as when the client catches it
        assert "argument 'grid' must be list[str]" in res.output, res.output
        res = runner.invoke(app, ["submit", "bracketed", "--arg", "grid=[]"], env={"COLUMNS": "400"})
        assert res.exit_code == 1 and "grid[0] is missing, want list[str]" in res.output, res.output
        res = runner.invoke(app, ["submit", "bracketed", "--arg", 'grid=["."]'], env={"COLUMNS": "400"})
        assert res.exit_code == 0 and "[bold]route[/bold] via bay[2]" in res.output, res.output
    finally:
        mem.close()
