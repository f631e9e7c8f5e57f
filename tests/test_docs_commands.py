"""The docs' shell blocks are true: like doctest, for the command line.

Every ```sh block of the README and the user pages in ``RUN`` runs here, in
process (``ramps ...`` through the CLI, in a scratch directory where
``examples/`` is the repository's), and must exit 0. A block that cannot run
here (it starts a node that runs until Ctrl-C, needs robots, ROS or root,
installs packages) says so in the Markdown just before it:

    <!-- not-tested: needs two robots -->

and a block that runs but takes seconds (figures drawn with matplotlib) is
marked ``<!-- slow: why -->`` and runs with the slow tests. Every ``ramps``
command of every shell block of the README and docs/ is also parsed against
the CLI itself, run or not: its subcommands and options must exist.
"""

from __future__ import annotations

import os
import re
import shlex
from dataclasses import dataclass
from functools import lru_cache
from itertools import takewhile
from pathlib import Path
from typing import Any

import pytest
import typer
from typer.testing import CliRunner

from ramps.cli import app

ROOT = Path(__file__).resolve().parent.parent
#: the pages whose unmarked blocks run; every user page is parsed
RUN = ["README.md", "docs/using-ramps.md", "docs/first-team.md", "docs/install.md", "docs/deploying.md"]
PAGES = ["README.md", *sorted(str(p.relative_to(ROOT)) for p in (ROOT / "docs").glob("*.md"))]
FENCE = re.compile(r"^```(\w*)\s*$")
MARK = re.compile(r"<!--\s*(not-tested|slow):\s*(.+?)\s*-->")
SEPARATORS = {"&&", "||", ";", "|", "&"}


@dataclass
class Block:
    page: str
    line: int
    text: str
    mark: str  # "", "not-tested" or "slow"
    why: str

    @property
    def id(self) -> str:
        return f"{self.page}:{self.line}"


def shell_blocks(page: str) -> list[Block]:
    """The sh/bash/shell blocks of a page, each with the mark just before it."""
    lines = (ROOT / page).read_text().splitlines()
    out, i = [], 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        if not m:
            i += 1
            continue
        end = next(j for j in range(i + 1, len(lines)) if lines[j].startswith("```"))
        if m.group(1) in ("sh", "bash", "shell"):
            before = next((lines[j] for j in range(i - 1, -1, -1) if lines[j].strip()), "")
            mark = MARK.search(before)
            out.append(Block(page, i + 1, "\n".join(lines[i + 1:end]), mark.group(1) if mark else "",
                             mark.group(2) if mark else ""))
        i = end + 1
    return out


def commands(text: str) -> list[list[str]]:
    """A block's simple commands as words: comments dropped, continuation lines
    joined, split at ``&&``, ``;``, pipes."""
    out: list[list[str]] = []
    for line in text.replace("\\\n", " ").splitlines():
        lex = shlex.shlex(line, posix=True, punctuation_chars=True)
        lex.whitespace_split = True
        current: list[str] = []
        for word in lex:
            if word in SEPARATORS:
                out.append(current)
                current = []
            else:
                current.append(word)
        out.append(current)
    return [c for c in out if c]


def ramps_words(words: list[str]) -> list[str] | None:
    """The arguments of a ``ramps`` command (after ``sudo``, ``VAR=value``,
    ``.venv/bin/ramps``), or None when the command is not ramps."""
    while words and (words[0] == "sudo" or re.match(r"[A-Z_]+=", words[0])):
        words = words[1:]
    if words and (words[0] == "ramps" or words[0].endswith("/ramps")):
        return words[1:]
    return None


@lru_cache(maxsize=1)
def cli() -> Any:
    """The ``ramps`` command tree as click sees it (built once: it takes a while)."""
    return typer.main.get_command(app)


def check_against_cli(args: list[str]) -> None:
    """Fail unless every subcommand and option of ``ramps ARGS`` exists."""
    cmd: Any = cli()
    path = "ramps"
    args = list(args)
    while hasattr(cmd, "commands") and args and not args[0].startswith("-"):
        name = args.pop(0)
        assert name in cmd.commands, f"`{path} {name}`: no such command (has {', '.join(sorted(cmd.commands))})"
        cmd, path = cmd.commands[name], f"{path} {name}"
    options: dict[str, Any] = {"--help": None}
    for param in cmd.params:
        if param.param_type_name == "option":
            for opt in [*param.opts, *param.secondary_opts]:
                options[opt] = param
    extra_ok = bool(cmd.context_settings.get("ignore_unknown_options"))
    takes_value = False
    for word in args:
        if takes_value:
            takes_value = False
            continue
        if word == "--" or (extra_ok and word == "--ros-args"):
            break
        if not word.startswith("-") or re.fullmatch(r"-\d[\d.]*", word):
            continue
        name = word.split("=", 1)[0]
        assert name in options, f"`{path}` has no option {name} (it has {', '.join(sorted(options))})"
        param = options[name]
        takes_value = param is not None and "=" not in word and not param.is_flag and not param.count


RUNNABLE = [b for page in RUN for b in shell_blocks(page) if b.mark != "not-tested"]
ALL = [b for page in PAGES for b in shell_blocks(page)]


@pytest.mark.parametrize("block", ALL, ids=lambda b: b.id)
def test_every_ramps_command_in_the_docs_exists(block: Block) -> None:
    for words in commands(block.text):
        args = ramps_words(words)
        if args is not None:
            try:
                check_against_cli(args)
            except AssertionError as exc:
                raise AssertionError(f"{block.id}: {shlex.join(words)}: {exc}") from None


def run_block(block: Block, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    (tmp_path / "examples").symlink_to(ROOT / "examples")
    monkeypatch.chdir(tmp_path)
    runner = CliRunner()
    for words in commands(block.text):
        if words[0] == "export":
            for assignment in words[1:]:
                key, _, value = assignment.partition("=")
                monkeypatch.setenv(key, value)
            continue
        args = ramps_words(words)
        assert args is not None, (f"{block.id}: `{shlex.join(words)}` is not a ramps command: mark the block "
                                  "<!-- not-tested: why --> if it cannot run here")
        env = dict(w.split("=", 1) for w in takewhile(lambda w: re.match(r"[A-Z_]+=", w), words))
        result = runner.invoke(app, args, env={**os.environ, **env}, catch_exceptions=False)
        assert result.exit_code == 0, f"{block.id}: `{shlex.join(words)}` exited {result.exit_code}:\n{result.output}"


@pytest.mark.parametrize("block", [b for b in RUNNABLE if b.mark != "slow"], ids=lambda b: b.id)
def test_the_docs_commands_run(block: Block, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    run_block(block, tmp_path, monkeypatch)


@pytest.mark.slow
@pytest.mark.parametrize("block", [b for b in RUNNABLE if b.mark == "slow"], ids=lambda b: b.id)
def test_the_docs_slow_commands_run(block: Block, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    run_block(block, tmp_path, monkeypatch)


def test_marks_say_why() -> None:
    for page in PAGES:
        for b in shell_blocks(page):
            assert b.mark == "" or len(b.why) > 3, f"{b.id}: say why the block is {b.mark}"


def test_the_checker_catches_what_does_not_exist() -> None:
    check_against_cli(["node", "--robot", "r1", "--no-multicast", "--node-nice", "-5", "--listen=tcp/0.0.0.0:7447"])
    check_against_cli(["ros", "--robot", "r1", "--ros-args", "-p", "team:=warehouse"])
    with pytest.raises(AssertionError, match="no option --colour"):
        check_against_cli(["status", "--colour"])
    with pytest.raises(AssertionError, match="no such command"):
        check_against_cli(["sim", "papers"])
