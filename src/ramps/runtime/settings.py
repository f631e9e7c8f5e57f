"""Settings of a ramps node or client: flags, environment, config file.

How this works: ``NodeSettings`` is validated data. ``load_settings`` merges,
from weakest to strongest: defaults, a TOML config file (``--config`` or
``RAMPS_CONFIG``), environment variables (``RAMPS_ROBOT``, ``RAMPS_TEAM``,
``RAMPS_LISTEN``, ``RAMPS_CONNECT``, ``RAMPS_CORES``, ...), then command-line
flags. Mistakes raise ``ConfigError`` naming the setting and its source.

The defaults work on a laptop: peer mode, listen on a free port of every
interface, find teammates by multicast scouting. On a network without
multicast, give each robot ``--connect`` endpoints of one or more others.

A config file looks like::

    robot = "r1"
    team = "warehouse"
    listen = ["tcp/0.0.0.0:7447"]
    connect = ["tcp/192.168.1.12:7447"]
    programs = ["mypkg.plans:replan"]

    [core]              # ramps.core.config.RampsConfig
    heartbeat_timeout = 2.0
"""

from __future__ import annotations

import os
import socket
import tomllib
from pathlib import Path
from typing import Any

import msgspec

from ramps.core.config import RampsConfig
from ramps.errors import ConfigError
from ramps.runtime import keys


class NodeSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    robot: str = ""
    team: str = "lab"
    #: Zenoh endpoints to listen on and to connect to
    listen: list[str] = msgspec.field(default_factory=lambda: ["tcp/0.0.0.0:0"])
    connect: list[str] = []
    #: find teammates by UDP multicast scouting
    multicast: bool = True
    #: cores offered to programs (default: detected, cgroup quota included)
    cores: int | None = None
    #: work units per second per core (default: measured at start)
    speed: float | None = None
    policy: str = "ramps"
    #: extra programs, as "package.module:function"
    programs: list[str] = []
    #: load publisher: seconds between reports and averaging window
    publish_period: float = 1.0
    window: float = 1.0
    #: Zenoh session lease, ms: how long a frozen or cut-off peer takes to be
    #: reported gone (keep-alives are sent 4 times per lease)
    lease_ms: int = 2000
    #: what the load publisher measures: host, cgroup, or auto (cgroup when
    #: the node runs in a cpu cgroup with a quota)
    load_scope: str = "auto"
    #: largest encoded arguments accepted from a client, bytes
    max_args_bytes: int = 1024 * 1024
    core: RampsConfig = RampsConfig()

    def __post_init__(self) -> None:
        if self.robot:
            keys.check_name("robot", self.robot)
        keys.check_name("team", self.team)
        if self.cores is not None and self.cores < 1:
            raise ValueError(f"cores must be >= 1, got {self.cores}")
        if self.speed is not None and not self.speed > 0:
            raise ValueError(f"speed must be > 0, got {self.speed}")
        if not self.publish_period > 0 or not 0 < self.window:
            raise ValueError("publish_period and window must be > 0")
        if self.lease_ms < 100:
            raise ValueError(f"lease_ms must be >= 100, got {self.lease_ms}")
        if self.load_scope not in ("auto", "host", "cgroup"):
            raise ValueError(f"load_scope must be auto, host or cgroup, got {self.load_scope!r}")


_ENV = {
    "RAMPS_ROBOT": ("robot", str),
    "RAMPS_TEAM": ("team", str),
    "RAMPS_LISTEN": ("listen", "list"),
    "RAMPS_CONNECT": ("connect", "list"),
    "RAMPS_MULTICAST": ("multicast", "bool"),
    "RAMPS_CORES": ("cores", int),
    "RAMPS_SPEED": ("speed", float),
    "RAMPS_POLICY": ("policy", str),
    "RAMPS_PROGRAMS": ("programs", "list"),
    "RAMPS_LEASE_MS": ("lease_ms", int),
}


def _from_env(environ: dict[str, str]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for var, (field, kind) in _ENV.items():
        raw = environ.get(var)
        if raw is None or raw == "":
            continue
        try:
            if kind == "list":
                out[field] = [x.strip() for x in raw.split(",") if x.strip()]
            elif kind == "bool":
                if raw.lower() not in ("1", "0", "true", "false", "yes", "no", "on", "off"):
                    raise ValueError(raw)
                out[field] = raw.lower() in ("1", "true", "yes", "on")
            else:
                out[field] = kind(raw)
        except ValueError:
            raise ConfigError(f"environment variable {var}={raw!r} is not a valid {field}") from None
    return out


def load_settings(*, config_file: str | os.PathLike | None = None, flags: dict[str, Any] | None = None,
                  environ: dict[str, str] | None = None, default_robot: bool = True) -> NodeSettings:
    environ = dict(os.environ if environ is None else environ)
    data: dict[str, Any] = {}
    path = config_file or environ.get("RAMPS_CONFIG")
    if path:
        try:
            data.update(tomllib.loads(Path(path).read_text()))
        except OSError as exc:
            raise ConfigError(f"cannot read config file {path}: {exc.strerror or exc}") from None
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"config file {path} is not valid TOML: {exc}") from None
    data.update(_from_env(environ))
    data.update({k: v for k, v in (flags or {}).items() if v is not None})
    if default_robot and not data.get("robot"):
        data["robot"] = keys.keys_safe_id(socket.gethostname())
    try:
        return msgspec.convert(data, NodeSettings)
    except msgspec.ValidationError as exc:
        raise ConfigError(f"bad setting: {exc}" + (f" (config file {path})" if path else "")) from None


def zenoh_config(s: NodeSettings, *, listen: list[str] | None = None):
    """A Zenoh peer configuration for these settings."""
    import json

    import zenoh

    c = zenoh.Config()
    c.insert_json5("mode", '"peer"')
    c.insert_json5("listen/endpoints", json.dumps(s.listen if listen is None else listen))
    c.insert_json5("connect/endpoints", json.dumps(s.connect))
    c.insert_json5("scouting/multicast/enabled", "true" if s.multicast else "false")
    c.insert_json5("transport/link/tx/lease", str(s.lease_ms))
    c.insert_json5("transport/link/tx/keep_alive", "4")
    return c
