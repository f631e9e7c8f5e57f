"""Settings of a ramps node or client: flags, environment, config file.

How this works: ``NodeSettings`` is validated data. ``load_settings`` merges,
from weakest to strongest: defaults, a TOML config file (``--config`` or
``RAMPS_CONFIG``), environment variables (``RAMPS_ROBOT``, ``RAMPS_TEAM``,
``RAMPS_LISTEN``, ``RAMPS_CONNECT``, ``RAMPS_CORES``, ...), then command-line
flags. Mistakes raise ``ConfigError`` naming the setting and its source.

A secured team (``secure = true``, ``RAMPS_SECURE``) uses ``tls/`` endpoints
only and each robot's credentials directory from ``ramps team add``
(``credentials``, ``RAMPS_CREDENTIALS``); see ``ramps.runtime.security``.

The defaults work on a laptop: peer mode, listen on a free port of every
interface, find teammates by multicast scouting. On a network without
multicast, give each robot ``--connect`` endpoints of one or more others.

Sites (docs/sites-and-routers.md): ``mode`` is Zenoh's mode, ``peer``
(links straight to every teammate it finds) or ``client`` (links to one
router only and reaches the team through it). ``ramps router`` opens a
Zenoh router from the same settings (``ramps.runtime.zenoh_configs``, which
turns these settings into Zenoh's configurations). ``zenoh`` holds
raw Zenoh settings applied last, by path (``[zenoh]`` table, ``--zenoh
KEY=VALUE``); the keys ramps sets from its own settings and, on a secured
team, the TLS and access-control keys are refused (``check_zenoh_overrides``).

A config file looks like::

    robot = "r1"
    team = "warehouse"
    listen = ["tcp/0.0.0.0:7447"]
    connect = ["tcp/192.168.1.12:7447"]
    programs = ["mypkg.plans:replan"]

    [commands.detect]   # an executable as a program (ramps.runtime.command)
    path = "/opt/robot/bin/detect"
    timeout = 120       # seconds, then its process group is killed

    [core]              # ramps.core.config.RampsConfig
    heartbeat_timeout = 2.0

    [zenoh]             # raw Zenoh settings, applied last (paths or nested tables)
    "transport/link/tx/batch_size" = 8192
"""

from __future__ import annotations

import os
import socket
import tomllib
from pathlib import Path
from typing import Annotated, Any, Literal

import msgspec

from ramps.core.config import RampsConfig
from ramps.core.wirelimits import MAX_NAME
from ramps.errors import ConfigError
from ramps.runtime import keys
from ramps.runtime.endpoints import check_endpoint, parse_metrics_address
from ramps.runtime.accelerators import check_setting as check_accelerators
from ramps.runtime.registry import MAX_ARGS_BYTES as _MAX_ARGS

class CommandEntry(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """An executable registered as a program (``ramps.runtime.command``)."""

    #: the executable (``~`` expanded, a relative path taken from the node's
    #: working directory); checked when the node starts
    path: str
    #: seconds it may run before its process group is killed
    timeout: float = 600.0
    #: fixed command-line arguments (the call's arguments come on stdin as JSON)
    args: list[str] = []
    #: expected work units, for placement (about CPU seconds on a reference core)
    work: float = 1.0
    #: run it only on the robot whose node it was submitted to (it touches
    #: that robot's hardware)
    local_only: bool = False

    def __post_init__(self) -> None:
        if not self.path:
            raise ValueError("a command needs a path")
        if not (0 < self.timeout < float("inf")):
            raise ValueError(f"command {self.path}: timeout must be > 0 seconds, got {self.timeout}")
        if not (0 <= self.work < float("inf")):
            raise ValueError(f"command {self.path}: work must be >= 0, got {self.work}")


def parse_commands(items: list[str]) -> dict[str, CommandEntry]:
    """``["detect=/opt/bin/detect", ...]`` (``--command``, ``RAMPS_COMMANDS``)."""
    out: dict[str, CommandEntry] = {}
    for item in items:
        name, sep, path = item.partition("=")
        if not sep or not name.strip() or not path.strip():
            raise ConfigError(f"--command must look like NAME=PATH, got {item!r}")
        out[name.strip()] = CommandEntry(path=path.strip())
    return out


#: Zenoh modes a node or client may take (a router is ``ramps router``)
MODES = ("peer", "client")

#: raw Zenoh keys ramps sets from its own settings: refused in ``zenoh`` (use the setting)
OWN_ZENOH_KEYS = {"mode": "--mode", "listen/endpoints": "--listen", "connect/endpoints": "--connect",
                  "scouting/multicast/enabled": "--multicast/--no-multicast", "transport/link/tx/lease": "--lease-ms",
                  "transport/shared_memory/enabled": "shared_memory"}
#: raw Zenoh keys a secured team's TLS and access control live under: refused when ``secure``
SECURE_ZENOH_PREFIXES = ("access_control", "transport/link/tls", "transport/link/protocols", "transport/auth")


def flatten_zenoh(table: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    """``{"transport": {"link": {"tx": {"batch_size": 8192}}}}`` or
    ``{"transport/link/tx/batch_size": 8192}`` -> ``{"transport/link/tx/batch_size": 8192}``:
    one entry per leaf, so an override replaces that value only, never a whole subtree."""
    out: dict[str, Any] = {}
    for k, v in table.items():
        key = f"{prefix}/{k.strip('/')}" if prefix else k.strip("/")
        if isinstance(v, dict) and v:
            out.update(flatten_zenoh(v, key))
        else:
            out[key] = v
    return out


def parse_zenoh_overrides(items: list[str]) -> dict[str, Any]:
    """``["transport/link/tx/batch_size=8192", ...]`` (``--zenoh``): the value is
    JSON (a number, true, a list, a quoted string) or else taken as a plain string."""
    import json

    out: dict[str, Any] = {}
    for item in items:
        key, sep, raw = item.partition("=")
        if not sep or not key.strip() or not raw.strip():
            raise ConfigError(f"--zenoh must look like KEY=VALUE, e.g. transport/link/tx/batch_size=8192, got {item!r}")
        try:
            out[key.strip().strip("/")] = json.loads(raw)
        except json.JSONDecodeError:
            out[key.strip().strip("/")] = raw.strip()
    return out


def check_zenoh_overrides(table: dict[str, Any], *, secure: bool) -> dict[str, Any]:
    """The leaves of a ``zenoh`` table, checked: no key that ramps sets from its own
    settings, none that would weaken a secured team, and each one accepted by
    Zenoh itself (its key and value). Raises ValueError naming the key."""
    import json

    flat = flatten_zenoh(table)
    if not flat:
        return flat
    import zenoh

    probe = zenoh.Config()
    for key, value in flat.items():
        if key in OWN_ZENOH_KEYS:
            raise ValueError(f"zenoh setting {key} is ramps's own: use {OWN_ZENOH_KEYS[key]} instead")
        if secure and any(key == p or key.startswith(p + "/") for p in SECURE_ZENOH_PREFIXES):
            raise ValueError(f"zenoh setting {key} is refused on a secured team: it would change the team's "
                             "TLS or access control (ramps.runtime.admission sets them)")
        try:
            probe.insert_json5(key, json.dumps(value))
        except (zenoh.ZError, TypeError, ValueError) as exc:
            why = str(exc).split(" at /")[0].removeprefix('Str("').removesuffix('")')
            raise ValueError(f"zenoh setting {key} = {json.dumps(value, default=str)}: Zenoh refused it "
                             f"({why})") from None
    return flat


class NodeSettings(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """A node's (or client's) settings; ``load_settings`` builds them. Each field's
    ``#:`` comment is its entry in docs/configuration.md (``ramps config reference``)."""

    #: this robot's name, unique in its team: 1-64 letters, digits, ``_``, ``-``
    #: or ``.``. Default: this host's name, which machines cloned from one disk
    #: image share, so give each robot its own
    robot: str = ""
    #: the team this node joins: teams on one network never hear each other
    team: str = "lab"
    #: Zenoh mode. ``peer``: links straight to every teammate it finds
    #: (multicast, gossip, ``connect``), for the robots of one network.
    #: ``client``: links to one router only (``connect = ["tcp/ROUTER:7447"]``,
    #: or found by multicast) and reaches every teammate through it, for robots
    #: that cannot or should not link to each other (client-isolated WiFi, many
    #: robots, another site reached only through routers). A client does not
    #: listen. See docs/sites-and-routers.md
    mode: str = "peer"
    #: Zenoh endpoints this node listens on for teammates, e.g.
    #: ``tcp/0.0.0.0:7447``. The default takes a free port on every interface,
    #: which teammates find by multicast; give a fixed port to robots that
    #: others ``connect`` to. ``tls/`` endpoints on a secured team
    listen: list[str] = msgspec.field(default_factory=lambda: ["tcp/0.0.0.0:0"])
    #: Zenoh endpoints of teammates (or of a router) to dial, e.g.
    #: ``tcp/192.168.1.12:7447``. Needed
    #: where multicast does not reach (most managed networks, loopback without
    #: multicast): list one or two seed robots, not every robot
    connect: list[str] = []
    #: find teammates by UDP multicast scouting (224.0.0.224:7446). Off
    #: (``--no-multicast``) where a network drops multicast or where nodes
    #: should meet only through ``connect``
    multicast: bool = True
    #: cores this robot offers to programs. Default: detected, a cgroup's CPU
    #: quota included (a container's or a pod's limit)
    cores: int | None = None
    #: work units a core of this robot computes per second (a unit is about a
    #: CPU second of a reference core). Default: measured at start and again
    #: while idle, so leave it unset except to pin a figure
    speed: float | None = None
    #: this robot's hardware class for its measured speed: robots of one class
    #: whose measurements differ by no more than their noise go by the class's
    #: median (docs/deploying.md, "Robots of one kind"). ``auto``: the CPU model; a name
    #: (``orin-nx-15w``) for robots an operator knows alike; empty: none
    speed_class: str = "auto"
    #: accelerators this robot advertises (docs/accelerators.md): ``auto``
    #: finds NVIDIA GPUs (with the ``nvidia-ml-py`` package) as ``cuda``;
    #: ``KIND[:COUNT[:SPEED]]`` declares one kind (``cuda:1:20``: one slot of
    #: 20 work units a second); ``:emulated`` after it makes slot locks stand
    #: in for a device (a testbed's); ``none`` advertises nothing
    accelerators: list[str] = msgspec.field(default_factory=lambda: ["auto"])
    #: placement policy: ``ramps`` (the cost model, default), ``paper``
    #: (faithful to the paper), ``round_robin``, ``random``, ``local_only``
    policy: str = "ramps"
    #: the node's own programs, as ``package.module:function``, each a
    #: function decorated with ``@ramps.program`` in a module installed on
    #: every robot (the bundled programs, and those of the ``ramps.programs``
    #: entry-point group, are always there)
    programs: list[str] = []
    #: executables as programs: ``[commands.NAME]`` tables in the config file,
    #: ``NAME=PATH`` with ``--command`` or ``RAMPS_COMMANDS`` (those take the
    #: table's defaults); the table's keys are listed below
    commands: dict[str, CommandEntry] = {}
    #: seconds between the load reports this node publishes (it also
    #: publishes one at once whenever its programs change)
    publish_period: float = 1.0
    #: seconds over which a load report averages the CPU use and run queue
    #: it samples every 0.2 s
    window: float = 1.0
    #: Zenoh session lease, ms: how long a frozen or cut-off teammate takes to
    #: be reported gone (keep-alives go 4 times per lease). 2000 ms raised no
    #: false alarm on a link with 20% loss and sub-second dropouts, 1500 ms
    #: 2-4 a minute (``python -m ramps.lab.detect --flap``); 1000 ms suits
    #: wired teams. At least 100
    lease_ms: int = 2000
    #: Zenoh's shared memory for messages over 64 KB between processes of one
    #: host: a robot's node and its local clients (both need it on; robots on
    #: separate hosts never share it). On, each process that sends such a
    #: message keeps a 16 MiB pool resident, mapped by each that receives
    #: from it. It saved 7-10 ms of about 30 on a 1 MB argument from a local
    #: client, nothing measurable at 100 KB or 4 MB
    #: (docs/lab/2026-11-27-footprint.md). Leave it off where robots are
    #: emulated on one host (the testbed), else their large messages bypass
    #: the emulated network
    shared_memory: bool = False
    #: the fork server also imports what the bundled programs import when they
    #: run (``route_plan``'s OR-Tools: about 70 MiB resident and 0.4 s of CPU
    #: at the start), so their first calls are as fast as later ones. Off, the
    #: first ``route_plan`` call in each worker imports it. The modules your own
    #: programs name in ``preload`` are imported either way
    preload_bundled: bool = False
    #: leave the team and exit with code 75 when a teammate is heard one way
    #: only (a split Zenoh session: docs/deploying.md), for the supervisor
    #: (systemd's ``Restart=``, a container's restart policy) to start the node
    #: again, which heals the split; its durable record keeps its programs.
    #: Off: the node only warns (``ramps_one_way_teammates``). Only under a
    #: supervisor: a node run by hand would stay out of the team
    restart_when_split: bool = False
    #: what the load publisher measures: ``host``, ``cgroup``, or ``auto``
    #: (``cgroup`` when the node runs in a cpu cgroup with a quota)
    load_scope: str = "auto"
    #: niceness of the worker processes that run programs (0-19): the node's
    #: own threads (heartbeats, replies) and the robot's own software come
    #: first, so a robot full of programs still answers its team at once.
    #: Load reports carry its CFS weight, so origins know that a program here
    #: gets what the robot's busy software leaves (0: equal shares)
    worker_nice: int = 10
    #: niceness the ``ramps node`` process gives itself (-20..19; below 0
    #: needs root or CAP_SYS_NICE, else one log line and it stays as it is):
    #: on a robot saturated by its own software the node's driver still gets
    #: the CPU to hear heartbeats and send its own. Its workers run at
    #: ``worker_nice``
    node_nice: int = -5
    #: largest encoded arguments accepted from a client, bytes (at most
    #: ``ramps.runtime.registry.MAX_ARGS_BYTES``, 8 MiB less 64 KiB: one
    #: message). The origin keeps each program's arguments until its result is
    #: in, to restart it elsewhere, so this times the programs in flight is
    #: memory
    max_args_bytes: int = _MAX_ARGS
    #: write every decision of the core (placed, accepted, failed,
    #: blacklisted, delivered, ...) to this file as JSON lines (``""``: off);
    #: ``ramps report`` draws it
    trace: str = ""
    #: also trace every message sent and received (``tx``/``rx``, with the
    #: time Zenoh handed it over) and every teammate appearing or vanishing
    #: (``peer_alive``/``peer_lost``): for chasing delays between robots
    trace_wire: bool = False
    #: a file holding this robot's battery charge, ``87`` (percent) or ``0.87``, read before each load
    #: report (``{robot}``: the robot's name); below ``[core] battery_reserve`` it hosts no teammates' programs
    battery_file: str = ""
    #: instead, a shell command that prints the charge, run at most once a report period (5 s at most)
    battery_command: str = ""
    #: without either, Linux's battery (``/sys/class/power_supply``) where the kernel lists one; false: none
    #: (robots emulated on one host share its battery: ``LocalTeam`` and the testbed turn it off)
    battery_sysfs: bool = True
    #: watts a busy core draws, or ``rapl`` (measured), for ``[core] energy_weight``; default: not known
    power_per_core: Annotated[float, msgspec.Meta(gt=0.0, le=1e9)] | Literal["rapl"] | None = None
    #: the decision core's timeouts, back-off and placement settings: the
    #: ``[core]`` table, listed below
    core: RampsConfig = RampsConfig()
    #: secured team: mutual TLS with team-CA certificates and Zenoh access
    #: control limited to the team's keys (docs/security.md)
    secure: bool = False
    #: this robot's credentials directory from ``ramps team add`` (``ca.pem``,
    #: ``cert.pem``, ``key.pem``)
    credentials: str = ""
    #: serve Prometheus metrics on this ``ADDR:PORT``, e.g. ``127.0.0.1:9464``
    #: (``""``: off; docs/observability.md)
    metrics: str = ""
    #: directory of this robot's durable record of the programs its clients
    #: submitted (``ramps.runtime.store``): a node restarted with it resumes
    #: them. ``off``: none. Default for ``ramps node``: ``$STATE_DIRECTORY``
    #: (systemd's ``StateDirectory=``), else ``~/.local/state/ramps``
    state_dir: str = ""
    #: how far each write of that record goes before the node acts on it:
    #: ``normal`` (to the operating system: it survives the node's crash or
    #: kill, and a robot's power loss but for its last moments' programs,
    #: whose clients on the robot lost power too) or ``full`` (fsynced: also
    #: the last moments, for clients on other machines; 0.5-2 ms a write)
    state_sync: str = "normal"
    #: the team CA's certificate, overriding ``credentials``'s ``ca.pem``
    ca: str = ""
    #: this robot's certificate, overriding ``credentials``'s ``cert.pem``
    cert: str = ""
    #: this robot's private key, overriding ``credentials``'s ``key.pem``
    key: str = ""
    #: secure mode: the robots admitted, by certificate name (default: any
    #: holder of a certificate from the team CA)
    members: list[str] = []
    #: raw Zenoh settings applied last, by path
    #: (``"transport/link/tx/batch_size" = 8192``) or as nested tables; the
    #: keys ramps sets from its own settings and, on a secured team, TLS and
    #: access control are refused
    zenoh: dict[str, Any] = {}

    def __post_init__(self) -> None:
        if self.robot:
            keys.check_name("robot", self.robot)
        keys.check_name("team", self.team)
        if self.cores is not None and self.cores < 1:
            raise ValueError(f"cores must be >= 1, got {self.cores}")
        if self.speed is not None and not self.speed > 0:
            raise ValueError(f"speed must be > 0, got {self.speed}")
        if len(self.speed_class) > MAX_NAME:
            raise ValueError(f"speed_class must be at most {MAX_NAME} characters, got {len(self.speed_class)}")
        check_accelerators(self.accelerators)
        if not self.publish_period > 0 or not 0 < self.window:
            raise ValueError("publish_period and window must be > 0")
        if self.lease_ms < 100:
            raise ValueError(f"lease_ms must be >= 100, got {self.lease_ms}")
        if not 0 <= self.worker_nice <= 19:
            raise ValueError(f"worker_nice must be 0..19, got {self.worker_nice}")
        if self.state_sync not in ("normal", "full"):
            raise ValueError(f"state_sync must be 'normal' or 'full', got {self.state_sync!r}")
        if not -20 <= self.node_nice <= 19:
            raise ValueError(f"node_nice must be -20..19, got {self.node_nice}")
        if self.load_scope not in ("auto", "host", "cgroup"):
            raise ValueError(f"load_scope must be auto, host or cgroup, got {self.load_scope!r}")
        if not 1 <= self.max_args_bytes <= _MAX_ARGS:
            raise ValueError(f"max_args_bytes must be 1..{_MAX_ARGS} (arguments travel in one message), "
                             f"got {self.max_args_bytes}")
        if self.metrics:
            parse_metrics_address(self.metrics)  # raises ValueError with a message
        self._check_security()
        self._check_mode()
        check_zenoh_overrides(self.zenoh, secure=self.secure)

    def _check_mode(self) -> None:
        if self.mode not in MODES:
            hint = " (a router is `ramps router`)" if self.mode == "router" else ""
            raise ValueError(f"mode must be peer or client, got {self.mode!r}{hint}")
        if self.mode == "client":
            if [e for e in self.listen if e != DEFAULT_LISTEN]:
                raise ValueError("client mode does not listen (it reaches the team through its router): "
                                 "drop --listen, or use --mode peer")
            if not self.connect and not self.multicast:
                raise ValueError("client mode needs a router: --connect tcp/ROUTER:7447 (or multicast "
                                 "scouting on, to find one on this network)")

    def _check_security(self) -> None:
        for e in self.listen + self.connect:
            check_endpoint(e)
        for m in self.members:
            keys.check_name("member", m)
        for e in self.connect + [e for e in self.listen if e != DEFAULT_LISTEN]:
            if self.secure and not e.startswith("tls/"):
                raise ValueError(f"secure mode uses TLS links only: write tls/{e.partition('/')[2]} instead of {e}")
            if not self.secure and e.startswith("tls/"):
                raise ValueError(f"endpoint {e} is TLS: TLS links need secure mode (--secure and --credentials)")
        if self.secure and not self.credentials and not (self.ca and self.cert and self.key):
            raise ValueError("secure mode needs this robot's credentials: --credentials DIR (from "
                             "`ramps team add ROBOT`) or env RAMPS_CREDENTIALS")

    def listen_endpoints(self, listen: list[str] | None = None) -> list[str]:
        """``listen`` (default: this robot's), the default made TLS in secure mode."""
        out = self.listen if listen is None else listen
        return [DEFAULT_TLS_LISTEN if self.secure and e == DEFAULT_LISTEN else e for e in out]


DEFAULT_LISTEN = "tcp/0.0.0.0:0"
DEFAULT_TLS_LISTEN = "tls/0.0.0.0:0"


#: how an environment variable's text becomes its setting: a type to call, or one of these forms
_EnvForm = Literal["list", "commands", "bool"]
_ENV: dict[str, tuple[str, _EnvForm | type[str] | type[int] | type[float]]] = {
    "RAMPS_ROBOT": ("robot", str),
    "RAMPS_TEAM": ("team", str),
    "RAMPS_LISTEN": ("listen", "list"),
    "RAMPS_CONNECT": ("connect", "list"),
    "RAMPS_MULTICAST": ("multicast", "bool"),
    "RAMPS_CORES": ("cores", int),
    "RAMPS_SPEED": ("speed", float),
    "RAMPS_SPEED_CLASS": ("speed_class", str),
    "RAMPS_ACCELERATORS": ("accelerators", "list"),
    "RAMPS_POLICY": ("policy", str),
    "RAMPS_PROGRAMS": ("programs", "list"),
    "RAMPS_COMMANDS": ("commands", "commands"),
    "RAMPS_LEASE_MS": ("lease_ms", int),
    "RAMPS_NODE_NICE": ("node_nice", int),
    "RAMPS_SHARED_MEMORY": ("shared_memory", "bool"),
    "RAMPS_PRELOAD_BUNDLED": ("preload_bundled", "bool"),
    "RAMPS_RESTART_WHEN_SPLIT": ("restart_when_split", "bool"),
    "RAMPS_SECURE": ("secure", "bool"),
    "RAMPS_CREDENTIALS": ("credentials", str),
    "RAMPS_MEMBERS": ("members", "list"),
    "RAMPS_TRACE": ("trace", str),
    "RAMPS_TRACE_WIRE": ("trace_wire", "bool"),
    "RAMPS_METRICS": ("metrics", str),
    "RAMPS_MODE": ("mode", str),
    "RAMPS_STATE_DIR": ("state_dir", str),
    "RAMPS_STATE_SYNC": ("state_sync", str),
    "RAMPS_BATTERY_FILE": ("battery_file", str),
    "RAMPS_BATTERY_COMMAND": ("battery_command", str),
    "RAMPS_BATTERY_SYSFS": ("battery_sysfs", "bool"),
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
            elif kind == "commands":
                try:
                    cmds = parse_commands([x.strip() for x in raw.split(",") if x.strip()])
                except ValueError as exc:
                    raise ConfigError(f"environment variable {var}={raw!r}: {exc} (NAME=PATH,NAME=PATH)") from None
                out[field] = {k: msgspec.to_builtins(v) for k, v in cmds.items()}
            elif kind == "bool":
                if raw.lower() not in ("1", "0", "true", "false", "yes", "no", "on", "off"):
                    raise ValueError(raw)
                out[field] = raw.lower() in ("1", "true", "yes", "on")
            else:
                out[field] = kind(raw)
        except ConfigError:
            raise
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
    flags = dict(flags or {})
    if flags.get("commands") is not None:  # --command adds to the config file's commands
        flags["commands"] = {**data.get("commands", {}), **flags["commands"]}
    if flags.get("zenoh") is not None:  # --zenoh adds to (and overrides) the config file's [zenoh]
        flags["zenoh"] = {**flatten_zenoh(data.get("zenoh", {})), **flatten_zenoh(flags["zenoh"])}
    data.update({k: v for k, v in flags.items() if v is not None})
    if default_robot and not data.get("robot"):
        data["robot"] = keys.keys_safe_id(socket.gethostname())
    try:
        return msgspec.convert(data, NodeSettings)
    except msgspec.ValidationError as exc:
        raise ConfigError(f"bad setting: {exc}" + (f" (config file {path})" if path else "")) from None
