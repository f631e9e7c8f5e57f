"""The configuration reference, docs/configuration.md, made from the settings themselves.

    ramps config reference > docs/configuration.md

Every key of a node's settings (``ramps.runtime.settings.NodeSettings``), of its
``[commands.NAME]`` tables (``CommandEntry``) and of its ``[core]`` table
(``ramps.core.config.RampsConfig``) is one row: its ``ramps node`` flag, its
environment variable (``_ENV``), its default and its meaning, which is the
``#:`` comment above the field in the source. A field whose comment is missing
fails here (``MissingDoc``); in ``RampsConfig`` a field without a comment of its
own belongs to the commented field above it. ``tests/test_config_reference.py``
fails when the committed page differs from what this prints.
"""

from __future__ import annotations

import inspect
import json
import re
from typing import Any

import msgspec

COMMAND = "ramps config reference > docs/configuration.md"

#: ``ramps node`` parameters whose setting has another name
FLAG_FIELD = {"program": "programs", "command": "commands", "accelerator": "accelerators"}
#: defaults that ``ramps node`` computes where the settings hold nothing
EFFECTIVE_DEFAULT = {
    "robot": "this host's name",
    "cores": "detected",
    "speed": "measured",
    "state_dir": "`$STATE_DIRECTORY`, else `~/.local/state/ramps`",
}
#: environment variables read outside the settings' own map
OTHER_ENVIRONMENT = [
    ("RAMPS_CONFIG", "the config file, when `--config` is not given"),
    ("STATE_DIRECTORY", "systemd's `StateDirectory=`: the default `state_dir` of `ramps node`"),
    ("NOTIFY_SOCKET, WATCHDOG_USEC, WATCHDOG_PID", "set by systemd for a `Type=notify` unit with "
     "`WatchdogSec=`: the node reports readiness and feeds the watchdog from its driver loop "
     "(docs/running-as-a-service.md)"),
    ("RAMPS_HEALTH_FILE", "where no service manager listens (a container): a file the node touches while "
     "its driver loop runs; `python -m ramps.runtime.service FILE` exits 0 while it is fresh (a HEALTHCHECK)"),
    ("ZENOH_RUNTIME", "Zenoh's thread pools; unset, ramps gives Zenoh 16 receive threads "
     "(`(rx: (worker_threads: 16))`); if you set it, include `rx` threads"),
    ("RUST_LOG", "Zenoh's own log, e.g. `RUST_LOG=zenoh=debug`"),
]


class MissingDoc(Exception):
    """A setting has no ``#:`` comment to document it."""


def field_comments(cls: type) -> dict[str, str | None]:
    """Each field of a struct class with the ``#:`` comment just above it (None
    when it has none), read from the class's source."""
    out: dict[str, str | None] = {}
    pending: list[str] = []
    for line in inspect.getsource(cls).splitlines()[1:]:
        stripped = line.strip()
        if stripped.startswith("#:"):
            pending.append(stripped[2:].strip())
            continue
        m = re.match(r"    ([a-z_][a-z0-9_]*)\s*:", line)
        if m and m.group(1) in cls.__struct_fields__:  # type: ignore[attr-defined]
            out[m.group(1)] = " ".join(pending) if pending else None
        if stripped:
            pending = []
    return out


def _markdown(text: str) -> str:
    """A comment's reStructuredText literals as Markdown, safe in a table cell."""
    text = re.sub(r"``(.+?)``", r"`\1`", text).replace("|", "\\|")
    return re.sub(r"\bdocs/([\w.-]+\.md)", r"[\1](\1)", text)


def _toml(value: Any) -> str:
    """A default as it would be written in the config file."""
    value = msgspec.to_builtins(value)
    if value is None:
        return "none"
    if value == {}:
        return "none"
    return "`" + json.dumps(value) + "`"


def _documented(cls: type, *, grouped: bool) -> list[tuple[str, str, Any]]:
    """``(field, meaning, default)`` for each field; ``grouped``: a field with no
    comment of its own belongs to the commented field above it."""
    comments = field_comments(cls)
    defaults = msgspec.structs.fields(cls)  # type: ignore[arg-type]
    rows, leader = [], None
    for f in defaults:
        text = comments.get(f.name)
        if text is None and not (grouped and leader):
            raise MissingDoc(f"{cls.__module__}.{cls.__name__}.{f.name} has no #: comment")
        if text is None:
            text = f"see `{leader}` above"
        else:
            leader = f.name
        default = f.default if f.default is not msgspec.NODEFAULT else (
            f.default_factory() if f.default_factory is not msgspec.NODEFAULT else None)
        rows.append((f.name, _markdown(text), default))
    return rows


def node_flags() -> tuple[dict[str, list[str]], list[tuple[list[str], str]]]:
    """The ``ramps node`` flags: those of each setting, and the flags that are
    no setting (with their help), read from the command ``ramps node`` runs."""
    import typer

    from ramps.cli.node import node as run_node

    one = typer.Typer(add_completion=False)
    one.command()(run_node)
    node = typer.main.get_command(one)  # a group of one command is that command
    by_field: dict[str, list[str]] = {}
    others: list[tuple[list[str], str]] = []
    from ramps.runtime.settings import NodeSettings

    for param in node.params:
        if param.param_type_name != "option":
            continue
        flags = [*param.opts, *param.secondary_opts]
        name = FLAG_FIELD.get(param.name or "", param.name or "")
        if name in NodeSettings.__struct_fields__:
            by_field[name] = flags
        elif "--help" not in flags:
            others.append((flags, getattr(param, "help", None) or ""))
    return by_field, others


def _env_by_field() -> dict[str, tuple[str, str]]:
    from ramps.runtime.settings import _ENV

    kinds = {"list": "comma-separated", "bool": "1/0, true/false, yes/no, on/off",
             "commands": "NAME=PATH,NAME=PATH"}
    return {field: (var, kinds.get(kind, "") if isinstance(kind, str) else "") for var, (field, kind) in _ENV.items()}


def reference() -> str:
    """The whole of docs/configuration.md: its introduction, then a section per table."""
    lines = _introduction() + _settings() + _commands() + _core() + _zenoh_and_environment()
    return "\n".join(lines) + "\n"


def _introduction() -> list[str]:
    """The page's title, where settings come from, an example file."""
    return [
        "# Configuration reference",
        "",
        f"<!-- Generated from the settings' own comments by `{COMMAND}`;",
        "     tests/test_config_reference.py fails when this page is out of date. Edit the",
        "     comments in src/ramps/runtime/settings.py and src/ramps/core/config.py, not this page. -->",
        "",
        "A node (`ramps node`) takes each setting from, strongest first: its command-line flag, its",
        "environment variable, the TOML config file (`--config FILE` or `RAMPS_CONFIG`), the default.",
        "`ramps submit`, `ramps status`, `ramps top` and `ramps.connect()` read the same environment",
        "and file for the settings they share (team, connect, multicast, mode, secure, credentials).",
        "`ramps config check FILE` checks a file with the node's own checks and prints the effective",
        "settings; a bad value stops a node at start with a message naming the setting and its source.",
        "",
        "```toml",
        "robot = \"r1\"",
        "team = \"warehouse\"",
        "listen = [\"tcp/0.0.0.0:7447\"]",
        "connect = [\"tcp/192.168.1.12:7447\"]",
        "programs = [\"mypkg.plans:replan\"]",
        "",
        "[commands.detect]",
        "path = \"/opt/robot/bin/detect\"",
        "timeout = 120",
        "",
        "[core]",
        "heartbeat_timeout = 2.0",
        "",
        "[zenoh]",
        "\"transport/link/tx/batch_size\" = 8192",
        "```",
    ]


def _settings() -> list[str]:
    """The node's settings, one row each, and the flags of ``ramps node`` that are no setting."""
    from ramps.runtime.settings import NodeSettings

    flags, other_flags = node_flags()
    env = _env_by_field()
    lines = [
        "",
        "## Settings",
        "",
        "| key | flag | environment | default | meaning |",
        "| --- | --- | --- | --- | --- |",
    ]
    for name, text, default in _documented(NodeSettings, grouped=False):
        flag = ", ".join(f"`{f}`" for f in flags.get(name, [])) or "-"
        var, fmt = env.get(name, ("", ""))
        envtext = f"`{var}`" + (f" ({fmt})" if fmt else "") if var else "-"
        shown = EFFECTIVE_DEFAULT.get(name) or ("table below" if name in ("core", "commands", "zenoh")
                                                 else _toml(default))
        lines.append(f"| `{name}` | {flag} | {envtext} | {shown} | {text} |")
    lines += ["", "Flags of `ramps node` that are no setting:", ""]
    for fl, helptext in other_flags:
        lines.append(f"- {', '.join(f'`{f}`' for f in fl)}: {_markdown(helptext)}")
    return lines


def _commands() -> list[str]:
    """The keys of a ``[commands.NAME]`` table."""
    from ramps.runtime.settings import CommandEntry

    lines = [
        "",
        "## `[commands.NAME]`: executables as programs",
        "",
        "`--command NAME=PATH` (repeatable) and `RAMPS_COMMANDS=NAME=PATH,...` give `path` and take",
        "the other keys' defaults; a `[commands.NAME]` table in the config file sets any of them. The",
        "executable gets its arguments as a JSON object on stdin and prints its result as JSON on",
        "stdout; a non-zero exit is a failure (the tail of its stderr goes to the caller);",
        "`RAMPS_PROGRESS 0.4` lines on stderr report progress (docs/ros2.md).",
        "",
        "| key | default | meaning |",
        "| --- | --- | --- |",
    ]
    for name, text, default in _documented(CommandEntry, grouped=False):
        lines.append(f"| `{name}` | {'required' if default is None else _toml(default)} | {text} |")
    return lines


def _core() -> list[str]:
    """The decision core's settings, the ``[core]`` table."""
    from ramps.core.config import RampsConfig

    lines = [
        "",
        "## `[core]`: the decision core",
        "",
        "Timeouts, back-off and placement settings of the sans-I/O core",
        "(`ramps.core.config.RampsConfig`), in seconds unless said. They have no flag and no",
        "environment variable. The defaults are for a team on WiFi running programs that take",
        "seconds to minutes.",
        "",
        "| key | default | meaning |",
        "| --- | --- | --- |",
    ]
    for name, text, default in _documented(RampsConfig, grouped=True):
        lines.append(f"| `{name}` | {_toml(default)} | {text} |")
    return lines


def _zenoh_and_environment() -> list[str]:
    """What ``[zenoh]`` may set, and the environment variables that are no setting."""
    from ramps.runtime.settings import OWN_ZENOH_KEYS, SECURE_ZENOH_PREFIXES

    lines = [
        "",
        "## `[zenoh]`: raw Zenoh settings",
        "",
        "Applied last, by path (`\"transport/link/tx/batch_size\" = 8192`) or as nested tables;",
        "`--zenoh KEY=VALUE` (repeatable, the value JSON or a plain string) adds to the table. Each",
        "is checked by Zenoh itself when the node starts. Refused, because ramps sets them from its",
        "own settings: " + ", ".join(f"`{k}` (use {v})" for k, v in OWN_ZENOH_KEYS.items()) + ".",
        "Refused on a secured team, because they would change its TLS or access control: "
        + ", ".join(f"`{p}`" for p in SECURE_ZENOH_PREFIXES) + ".",
        "",
        "## Other environment variables",
        "",
        "| variable | meaning |",
        "| --- | --- |",
    ]
    for var, text in OTHER_ENVIRONMENT:
        lines.append(f"| `{var}` | {text} |")
    return lines


if __name__ == "__main__":
    print(reference(), end="")
