"""``ramps config check FILE``: a node's config file, checked before a (re)start.

How this works: the node's own validation is the one truth (``NodeSettings``
and its ``__post_init__``, ``load_settings``, the registry, the credential
checks); this module only runs it piece by piece so that one run names every
problem, one line each, instead of the first one the node would stop at:

1. the file parses as TOML;
2. every key is a setting (``NodeSettings``' fields, and in ``[core]`` and
   ``[commands.NAME]`` those of their records), an unknown one with the
   nearest known name ("did you mean");
3. every value has its setting's type (``msgspec.convert`` of that value to
   that field's type, as ``load_settings`` converts the whole file);
4. the values together pass ``NodeSettings``' checks (ranges, endpoints,
   secure mode with credentials and TLS links ...): while they fail, the
   setting whose removal changes the failure is named and set aside, so
   independent mistakes are all reported;
5. what the node checks only when it starts: the policy exists, each program
   imports, each command is an executable, secure mode's credentials are
   readable and for this robot and team;
6. last, the file through ``load_settings`` itself, with the environment
   given (an ``EnvironmentFile`` such as /etc/ramps/node.env), as the node
   will read it.

Rules: no side effects beyond importing the programs named in the file (the
node imports them too); never raises for a user mistake: every one is a
``Problem``.
"""

from __future__ import annotations

import difflib
import os
import tomllib
from pathlib import Path
from typing import Any, Mapping

import msgspec

from ramps.errors import ConfigError, RampsError
from ramps.runtime.settings import NodeSettings, load_settings


class Problem(msgspec.Struct, frozen=True, kw_only=True):
    """One mistake in a config file: ``setting`` is its dotted key ("" for the file)."""

    setting: str
    message: str

    def __str__(self) -> str:
        return f"{self.setting}: {self.message}" if self.setting else self.message


class CheckResult(msgspec.Struct, frozen=True, kw_only=True):
    path: str
    problems: list[Problem]
    #: the effective settings (file, environment given, defaults) when there is no problem
    settings: NodeSettings | None = None

    @property
    def ok(self) -> bool:
        return not self.problems


def _fields(struct: type[msgspec.Struct]) -> dict[str, Any]:
    return {f.encode_name: f.type for f in msgspec.structs.fields(struct)}


def _struct_type(tp: Any) -> type[msgspec.Struct] | None:
    return tp if isinstance(tp, type) and issubclass(tp, msgspec.Struct) else None


def _dict_of_struct(tp: Any) -> type[msgspec.Struct] | None:
    """``X`` for a field typed ``dict[str, X]`` with ``X`` a record (``commands``)."""
    args = getattr(tp, "__args__", None)
    if getattr(tp, "__origin__", None) is dict and args and len(args) == 2:
        return _struct_type(args[1])
    return None


def _message(exc: BaseException) -> str:
    """The node's message, without load_settings' prefix or msgspec's ``- at `$.x```
    (the setting is named beside it)."""
    text = str(exc).removeprefix("bad setting: ")
    head, sep, _ = text.rpartition(" - at `$")
    return head if sep else text


def unknown_keys(data: Mapping[str, Any], struct: type[msgspec.Struct] = NodeSettings,
                 prefix: str = "") -> list[Problem]:
    """Keys that are no setting of ``struct`` (recursing into records and
    tables of records), each with the nearest known name."""
    known = _fields(struct)
    out: list[Problem] = []
    for key, value in data.items():
        where = f"{prefix}{key}"
        if key not in known:
            near = difflib.get_close_matches(key, list(known), n=1, cutoff=0.6)
            hint = f" (did you mean {prefix}{near[0]}?)" if near else ""
            out.append(Problem(setting=where, message=f"unknown setting{hint}"))
            continue
        tp = known[key]
        inner = _struct_type(tp)
        if inner is not None and isinstance(value, dict):
            out.extend(unknown_keys(value, inner, prefix=f"{where}."))
        entry = _dict_of_struct(tp)
        if entry is not None and isinstance(value, dict):
            for name, sub in value.items():
                if isinstance(sub, dict):
                    out.extend(unknown_keys(sub, entry, prefix=f"{where}.{name}."))
    return out


def _drop_unknown(data: dict[str, Any], struct: type[msgspec.Struct] = NodeSettings) -> dict[str, Any]:
    known = _fields(struct)
    out: dict[str, Any] = {}
    for key, value in data.items():
        if key not in known:
            continue
        tp = known[key]
        inner, entry = _struct_type(tp), _dict_of_struct(tp)
        if inner is not None and isinstance(value, dict):
            value = _drop_unknown(value, inner)
        elif entry is not None and isinstance(value, dict):
            value = {n: _drop_unknown(v, entry) if isinstance(v, dict) else v for n, v in value.items()}
        out[key] = value
    return out


def wrong_types(data: dict[str, Any]) -> tuple[dict[str, Any], list[Problem]]:
    """The settings whose value has its field's type (records are converted,
    so their own checks run), and a problem for each one that has not."""
    known = _fields(NodeSettings)
    good: dict[str, Any] = {}
    out: list[Problem] = []
    for key, value in data.items():
        try:
            msgspec.convert(value, known[key])
        except msgspec.ValidationError as exc:
            out.append(Problem(setting=key, message=_type_message(exc, key)))
            continue
        good[key] = value
    return good, out


def _type_message(exc: msgspec.ValidationError, key: str) -> str:
    """msgspec says ``Expected `int`, got `str` - at `$[0]```: name the key instead of ``$``."""
    text = str(exc)
    head, sep, where = text.partition(" - at `$")
    if sep:
        path = where.rstrip("`")
        return f"{head} (at {key}{path})" if path else head
    return text


def _convert(data: dict[str, Any]) -> str | None:
    """None if ``data`` makes valid ``NodeSettings``, else the node's message."""
    try:
        msgspec.convert(data, NodeSettings)
    except (msgspec.ValidationError, ValueError, ConfigError) as exc:
        return _message(exc)
    return None


def value_problems(data: dict[str, Any], *, robot: str) -> tuple[dict[str, Any], list[Problem]]:
    """``NodeSettings``' own checks over the well-typed settings: each failure
    is blamed on the setting whose removal changes it (set aside, then the
    rest checked again), so that every independent mistake is named. Also
    the settings that are left, valid together (unless a failure named none)."""
    rest = dict(data)
    rest.setdefault("robot", robot)
    out: list[Problem] = []
    for _ in range(len(rest) + 1):
        error = _convert(rest)
        if error is None:
            break
        culprit = next((k for k in rest if k != "robot" and _convert({kk: v for kk, v in rest.items() if kk != k})
                        != error), None)
        if culprit is None and "robot" in data:
            culprit = "robot" if _convert({**rest, "robot": "r1"}) != error else None
        out.append(Problem(setting=culprit or "", message=error))
        if culprit is None:
            break
        rest.pop(culprit)
    return rest, out


def start_problems(s: NodeSettings) -> list[Problem]:
    """What the node checks only as it starts: the policy, the programs and
    commands it registers, a secured team's credentials."""
    from ramps.core.policy import POLICIES
    from ramps.runtime.registry import Registry, default_registry

    out: list[Problem] = []
    if s.policy not in POLICIES:
        out.append(Problem(setting="policy", message=f"unknown policy {s.policy!r}; choose one of {', '.join(POLICIES)}"))
    registry = Registry(dict(default_registry._specs))
    for target in s.programs:
        try:
            registry.add_target(target)
        except Exception as exc:  # an import error of the user's module is what we report
            out.append(Problem(setting="programs", message=f"{target}: {_message(exc)}"))
    for name, cmd in s.commands.items():
        try:
            registry.add_command(name, cmd.path, timeout=cmd.timeout, args=cmd.args, work=cmd.work,
                                 local_only=cmd.local_only)
        except (RampsError, ValueError, OSError) as exc:
            out.append(Problem(setting=f"commands.{name}", message=_message(exc)))
    if s.secure:
        from ramps.runtime.credentials import settings_credentials

        try:
            settings_credentials(s, robot=s.robot)
        except (RampsError, ValueError, OSError) as exc:
            out.append(Problem(setting="credentials", message=_message(exc)))
    return out


def read_env_file(path: str | os.PathLike) -> dict[str, str]:
    """``KEY=VALUE`` lines as systemd's ``EnvironmentFile=`` reads them
    (comments, blank lines, optional quotes, ``export`` ignored)."""
    env: dict[str, str] = {}
    for line in Path(path).read_text().splitlines():
        line = line.strip()
        if not line or line[0] in "#;":
            continue
        key, sep, value = line.removeprefix("export ").partition("=")
        if not sep:
            raise ConfigError(f"environment file {path}: {line!r} is not KEY=VALUE")
        value = value.strip()
        if len(value) >= 2 and value[0] == value[-1] and value[0] in "'\"":
            value = value[1:-1]
        env[key.strip()] = value
    return env


def check_config(path: str | os.PathLike, *, environ: Mapping[str, str] | None = None,
                 robot: str | None = None) -> CheckResult:
    """Every problem of the config file at ``path``, read as ``ramps node
    --config`` reads it with ``environ`` (default: none; ``RAMPS_*``
    variables override the file), and the effective settings when it has none."""
    import socket

    from ramps.runtime import keys

    where = str(path)
    env = dict(environ or {})
    env.pop("RAMPS_CONFIG", None)  # the file checked is this one
    try:
        data = tomllib.loads(Path(path).read_text())
    except OSError as exc:
        return CheckResult(path=where, problems=[Problem(setting="", message=f"cannot read {where}: "
                                                         f"{exc.strerror or exc}")])
    except tomllib.TOMLDecodeError as exc:
        return CheckResult(path=where, problems=[Problem(setting="", message=f"not valid TOML: {exc}")])
    default_robot = robot or keys.keys_safe_id(socket.gethostname())
    problems = unknown_keys(data)
    good, typed = wrong_types(_drop_unknown(data))
    problems += typed
    rest, valued = value_problems(good, robot=default_robot)
    problems += valued
    if problems:  # what the node would check at start, of the settings that are valid
        try:
            partial = msgspec.convert(rest, NodeSettings)
        except (msgspec.ValidationError, ValueError):
            return CheckResult(path=where, problems=problems)
        return CheckResult(path=where, problems=problems + start_problems(partial))
    try:  # the node's own reading, environment included: the one truth
        s = load_settings(config_file=path, environ=env, flags={"robot": robot} if robot else None)
    except ConfigError as exc:
        return CheckResult(path=where, problems=[Problem(setting="", message=_message(exc))])
    problems = start_problems(s)
    return CheckResult(path=where, problems=problems, settings=None if problems else s)


def summary(s: NodeSettings) -> list[tuple[str, str]]:
    """The effective settings a person checks first, as (name, value) rows,
    then every other setting that differs from its default."""
    from ramps.runtime.registry import default_registry

    def onoff(b: bool) -> str:
        return "on" if b else "off"

    mode = getattr(s, "mode", "peer")
    rows = [
        ("robot", s.robot),
        ("team", s.team),
        ("mode", str(mode)),
        ("listen", ", ".join(s.listen_endpoints()) or "-"),
        ("connect", ", ".join(s.connect) or "-"),
        ("multicast", onoff(s.multicast)),
        ("cores", "detected at start (cgroup quota included)" if s.cores is None else str(s.cores)),
        ("speed", "measured at start" if s.speed is None else f"{s.speed:g}"),
        ("policy", s.policy),
        ("programs", ", ".join(sorted(default_registry.names()) + list(s.programs))),
        ("commands", ", ".join(f"{n} ({c.path}, {c.timeout:g} s)" for n, c in s.commands.items()) or "-"),
        ("security", (f"secure: TLS with team certificates from {s.credentials or s.cert}" if s.secure
                      else "INSECURE: anyone who reaches this network can join the team and run programs")),
        ("metrics", s.metrics or "off"),
        ("trace", s.trace or "off"),
    ]
    shown = {name for name, _ in rows} | {"credentials", "cert", "ca", "key"}
    defaults = NodeSettings(robot=s.robot)
    for f in msgspec.structs.fields(NodeSettings):
        if f.name in shown:
            continue
        value, default = getattr(s, f.name), getattr(defaults, f.name)
        if value == default:
            continue
        if isinstance(value, msgspec.Struct):
            for sub in msgspec.structs.fields(type(value)):
                v, d = getattr(value, sub.name), getattr(default, sub.name)
                if v != d:
                    rows.append((f"{f.name}.{sub.name}", str(v)))
        else:
            rows.append((f.name, str(value)))
    return rows


__all__ = ["CheckResult", "Problem", "check_config", "read_env_file", "summary", "unknown_keys"]
