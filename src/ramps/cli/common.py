"""What every ``ramps`` command group shares: the consoles, the error exit,
argument checks, JSON output, the node settings, commands' help, and the options several
commands take (``--team``, ``--connect``, ``--secure``, ``--credentials``...),
declared once here as ``Annotated`` types.

``--help`` names what to type: ``--connect ENDPOINT``, ``--timeout SECONDS``,
an argument ``ROBOT``, from one table, ``VALUE_NAMES`` (by the option's long name or the
argument's name; ``metavar=`` on one option wins, and an option not in the table is
named by its type, ``N`` for an integer); a flag shows no value, and a range of
values reads in words, ``[default: 4; 1 to 16]``, where it is more than a count's
or a duration's lower bound of 0 or 1. Every command of a group that
``command_group`` makes is a ``RampsCommand``, which does this.

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
from typer.core import TyperCommand
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


#: the name ``--help`` gives the value of an option (by its long name) or an argument (by
#: its name); an option not here is named by its type (VALUE_NAMES_BY_TYPE)
VALUE_NAMES: dict[str, str] = {
    # where to reach the team, and who this is
    "--connect": "ENDPOINT", "--listen": "ENDPOINT", "--metrics": "ADDR:PORT", "--host": "HOST",
    "--team": "NAME", "--robot": "NAME", "--namespace": "NAMESPACE", "--mode": "MODE",
    "--discovery": "HOW", "--tb": "ID", "--kill": "ROBOT", "--loaded": "ROBOT",
    "--zenoh": "KEY=VALUE", "--set": "KEY=VALUE", "--arg": "NAME=VALUE", "--command": "NAME=PATH",
    "--program": "MODULE:FUNCTION", "--policy": "POLICY",
    # files and folders
    "--config": "FILE", "--env-file": "FILE", "--out": "FILE", "--report": "FILE", "--trace": "FILE",
    "--credentials": "DIR", "--dir": "DIR", "--state-dir": "DIR", "--keep-logs": "DIR", "--plot": "DIR",
    "--png": "DIR",
    # durations
    "--at": "SECONDS", "--checkpoint-every": "SECONDS", "--connect-timeout": "SECONDS", "--cut": "SECONDS",
    "--diagnostics-period": "SECONDS", "--down": "SECONDS", "--duration": "SECONDS",
    "--exact-seconds": "SECONDS", "--exit-after": "SECONDS", "--gap": "SECONDS", "--goal-timeout": "SECONDS",
    "--interval": "SECONDS", "--kill-at": "SECONDS", "--load-at": "SECONDS", "--online-seconds": "SECONDS",
    "--origin-grace": "SECONDS", "--origin-hold": "SECONDS", "--outage": "SECONDS", "--period": "SECONDS", "--scrape-every": "SECONDS",
    "--seconds": "SECONDS", "--settle": "SECONDS", "--timeout": "SECONDS", "--wait": "SECONDS",
    "--lease-ms": "MS", "--days": "DAYS",
    # amounts
    "--quota": "CORES", "--work": "UNITS", "--units": "UNITS", "--speed": "UNITS/S", "--rate": "RATE",
    "--payload": "BYTES", "--origin-faults": "CHANCE", "--node-nice": "NICENESS",
    "--peer-nice": "NICENESS", "--seed": "SEED", "--only-seed": "SEED",
    # names from a list the help gives
    "--scenario": "NAME", "--only": "NAME", "--engine": "NAME", "--variant": "NAME", "--experiment": "NAME",
    "--family": "NAME", "--kind": "KIND", "--size": "SIZE", "--case": "PROGRAMS,BUSY", "--title": "TEXT",
    # arguments
    "paths": "FILE...", "scenario": "FILE", "file": "FILE", "robots": "ROBOT...", "loss": "PROBABILITY",
}
#: the name of a value that no entry of VALUE_NAMES names, by its Python type
VALUE_NAMES_BY_TYPE: dict[Any, str] = {int: "N", float: "NUMBER", Path: "PATH"}


def value_name(param: Any) -> str:
    """What ``--help`` calls the value of ``param`` (a command's parameter): its own
    ``metavar``, else VALUE_NAMES's entry, else an argument's own name or a name by type."""
    if param.metavar is not None:
        return str(param.metavar)
    if param.param_type_name == "argument":
        return VALUE_NAMES.get(param.name, param.name.upper() + ("..." if param.nargs != 1 else ""))
    long_name = max(param.opts, key=len)
    if long_name in VALUE_NAMES:
        return VALUE_NAMES[long_name]
    annotation = getattr(getattr(param, "type_descriptor", None), "annotation", None)
    element = getattr(annotation, "__args__", (annotation,))[0]  # list[int] -> int
    return VALUE_NAMES_BY_TYPE.get(element, "VALUE")


def _number(value: float) -> str:
    return str(int(value)) if float(value).is_integer() else str(value)


def range_in_words(param: Any) -> tuple[str, Optional[str]]:
    """A number range as typer writes it in ``--help`` (``1<=x<=500``, ``x>=10``;
    "" when ``param`` has none) and in words (``1 to 500``, ``at least 10``;
    None where it says nothing new: a lower bound of 0 or 1 alone)."""
    lo: Optional[float] = getattr(param, "min", None)
    hi: Optional[float] = getattr(param, "max", None)
    if lo is None and hi is None:
        return "", None
    if hi is None:
        assert lo is not None
        return f"x>={lo}", None if lo in (0, 1) else f"at least {_number(lo)}"
    if lo is None:
        return f"x<={hi}", f"at most {_number(hi)}"
    return f"{lo}<=x<={hi}", f"{_number(lo)} to {_number(hi)}"


def _in_words(text: str, param: Any) -> str:
    """``text`` (a parameter's help, with typer's ``[default: ...; range]``) with its range in words or left out."""
    typer_range, words = range_in_words(param)
    if not typer_range or typer_range not in text:
        return text
    if words:
        return text.replace(typer_range, words)
    return (text.replace(f"  [{typer_range}]", "").replace(f"; {typer_range}", "")
            .replace(f"[{typer_range}; ", "["))


class RampsCommand(TyperCommand):
    """A ramps command: its options' and arguments' values named from VALUE_NAMES,
    and its ``--help`` free of typer's type placeholders (``<int range>``, ``<str>``)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        for param in self.params:
            if not getattr(param, "is_flag", False):
                param.metavar = value_name(param)

    def format_options(self, ctx: Any, formatter: Any) -> None:
        """typer's layout (Arguments, then Options), with an argument named by its
        value alone (``ROBOT``, not ``robot <str>``) and ranges in words."""
        sections: dict[str, list[tuple[str, str]]] = {"Arguments": [], "Options": []}
        for param in self.get_params(ctx):
            record = param.get_help_record(ctx)
            if record is None:
                continue
            name, text = record
            if param.param_type_name == "argument":
                sections["Arguments"].append((value_name(param), _in_words(text, param)))
            else:
                sections["Options"].append((name, _in_words(text, param)))
        for title, rows in sections.items():
            if rows:
                with formatter.section(title):
                    formatter.write_dl(rows)


class RampsTyper(typer.Typer):
    """A command group whose commands are ``RampsCommand``s, also one that asks for
    a class of its own (``cls=``, as ``ramps ros``'s parsing): that class with
    ``RampsCommand`` mixed in."""

    def command(self, name: Optional[str] = None, *, cls: Optional[type[TyperCommand]] = None,
                **settings: Any) -> Callable[[Any], Any]:
        if cls is None:
            cls = RampsCommand
        elif not issubclass(cls, RampsCommand):
            cls = type(cls.__name__, (cls, RampsCommand), {"__doc__": cls.__doc__})
        return super().command(name, cls=cls, **settings)


def command_group(help: str, **settings: Any) -> typer.Typer:
    """A ``ramps`` command group whose help is click's plain layout, not rich's
    panels: rich's option table shrinks the option-name column to fit the
    terminal, so at 80 columns it cuts a long name (``--diagnostics-pe…``),
    while click's puts such a name on a line of its own and wraps the help
    below it. Help strings are plain text: no rich markup, no ``\\[`` escapes.
    Its commands name their values (``RampsCommand``)."""
    return RampsTyper(help=help, no_args_is_help=True, rich_markup_mode=None, **settings)


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
