"""What every ``ramps`` command group shares: the consoles, the error exit,
argument checks, JSON output, the node settings, commands' help, and the options several
commands take (``--team``, ``--connect``, ``--secure``, ``--credentials``...),
declared once here as ``Annotated`` types.

Rules: the CLI parses, calls the library, prints. User mistakes (a bad
scenario file, an unknown policy) end with a one-line message and exit code
2 (``fail``), never a traceback. Long work shows progress on stderr so
``--json`` output on stdout stays clean for scripts.
"""

from __future__ import annotations

import inspect
import sys
from pathlib import Path
from typing import Annotated, Any, Callable, NoReturn, Optional

import msgspec
import typer
from rich.console import Console
from rich.markup import escape

# a pipe or a CI log gets wide tables instead of wrapped ones
out = Console(width=None if sys.stdout.isatty() else 200)
err = Console(stderr=True)

POLICY_HELP = "placement policy: ramps (default, ours), paper (faithful to the paper), round_robin, random, local_only"
DISCOVERY_HELP = ("how testbed robots find each other: both (multicast plus a seed robot), multicast, "
                  "or connect (explicit endpoints only)")
TEAM_HELP = "team name: teams on one network never hear each other (env RAMPS_TEAM)"
SECURE_HELP = "secured team: TLS links, team certificates, access control (env RAMPS_SECURE; see `ramps team`)"
CREDENTIALS_HELP = "this robot's credentials directory from `ramps team add` (env RAMPS_CREDENTIALS)"
CONNECT_HELP = "Zenoh endpoint of a teammate, e.g. tcp/192.168.1.12:7447 (repeatable; env RAMPS_CONNECT)"

# the options shared by several commands (typer copies the option info for each command)
TeamOption = Annotated[Optional[str], typer.Option("--team", "-t", help=TEAM_HELP)]
ConnectOption = Annotated[Optional[list[str]], typer.Option("--connect", "-c", help=CONNECT_HELP)]
FindTeamOption = Annotated[Optional[bool], typer.Option("--multicast/--no-multicast",
                                                        help="find the team by UDP multicast")]
SecureOption = Annotated[bool, typer.Option("--secure", help=SECURE_HELP)]
CredentialsOption = Annotated[Optional[Path], typer.Option("--credentials", help=CREDENTIALS_HELP)]
PolicyOption = Annotated[Optional[str], typer.Option("--policy", "-p", help=POLICY_HELP)]
DiscoveryOption = Annotated[str, typer.Option("--discovery", help=DISCOVERY_HELP)]
LeaseOption = Annotated[Optional[int], typer.Option("--lease-ms", help="Zenoh lease of every node, ms")]


def command_group(help: str, **settings: Any) -> typer.Typer:
    """A ``ramps`` command group whose help is click's plain layout, not rich's
    panels: rich's option table shrinks the option-name column to fit the
    terminal, so at 80 columns a long name was cut (``--diagnostics-pe…``),
    while click's puts such a name on a line of its own and wraps the help
    below it. Help strings are plain text: no rich markup, no ``\\[`` escapes."""
    return typer.Typer(help=help, no_args_is_help=True, rich_markup_mode=None, **settings)


def command_help(command: Callable[..., Any]) -> str:
    """A command's ``--help`` text: its docstring without the paragraph that starts "Long because",
    which tells the code's readers why the function is long (docs/architecture.md, "Development")."""
    paragraphs = (inspect.getdoc(command) or "").split("\n\n")
    return "\n\n".join(p for p in paragraphs if not p.startswith("Long because"))


def fail(message: str, code: int = 2) -> NoReturn:
    err.print(f"[bold red]error:[/] {escape(message)}", highlight=False, soft_wrap=True)  # "[route]" is no markup
    raise typer.Exit(code)


def check_policy(policy: str) -> None:
    from ramps.core.policy import POLICIES

    if policy not in POLICIES:
        fail(f"unknown policy {policy!r}; choose one of {', '.join(POLICIES)}")


def check_discovery(discovery: str) -> None:
    if discovery not in ("both", "multicast", "connect"):
        fail(f"unknown discovery {discovery!r}; choose both, multicast or connect")


def fault_plans(mode: str, kind: str, kinds: tuple[str, ...] | list[str]) -> tuple[list[str], list[str]]:
    """The failure modes and kinds a ``--mode``/``--kind`` pair asks for
    (``all`` = every one), or a clear error."""
    modes = ["sequential", "simultaneous"] if mode == "all" else [mode]
    chosen = list(kinds) if kind == "all" else [kind]
    if any(m not in ("sequential", "simultaneous") for m in modes):
        fail(f"unknown mode {mode!r}; choose sequential, simultaneous or all")
    if any(k not in kinds for k in chosen):
        fail(f"unknown kind {kind!r}; choose {', '.join(kinds)} or all")
    return modes, chosen


def emit(reports: list[Any], printer: Callable[[Any, Console], None], *, as_json: bool,
         out_file: Optional[Path]) -> None:
    """Print results as tables (``printer(report, console)`` for each) or as
    JSON on stdout (one report, or ``{"experiments": [...]}``), and save the
    JSON to ``out_file`` too when given."""
    data = msgspec.json.encode(reports[0] if len(reports) == 1 else {"experiments": reports})
    if as_json:
        sys.stdout.write(data.decode() + "\n")
    else:
        for rep in reports:
            printer(rep, out)
    if out_file is not None:
        save_json(data, out_file)
        err.print(f"wrote {out_file}")


def save_json(data: bytes, out_file: Path) -> None:
    out_file.parent.mkdir(parents=True, exist_ok=True)
    out_file.write_bytes(data + b"\n")


def node_settings(**flags: Any) -> Any:
    """The node settings from flags (None = not given), config file and environment; a bad value is a user error."""
    from ramps.errors import ConfigError
    from ramps.runtime.settings import load_settings

    config_file = flags.pop("config_file", None)
    default_robot = flags.pop("default_robot", True)
    try:
        return load_settings(config_file=config_file, flags=flags, default_robot=default_robot)
    except ConfigError as exc:
        fail(str(exc))
