"""What a simulated experiment is: the team, the workload, the faults.

Rules: plain, frozen data. ``Scenario`` is what ``ramps sim run FILE`` reads
(see ``ramps.sim.scenario_file`` for the YAML loader and its error messages)
and what the paper's experiments build in code. ``Scenario.check()`` raises
``ScenarioError`` naming the field at fault as a path such as
``$.robots[2].cores``; loaders translate that path to a line of the file.

Units: time in seconds, ``work`` in work units, ``speed`` in work units per
second per core (a Raspberry Pi 3 core running the paper's route planner is
speed 1.0 and one route-planning program is 53 units), sizes in bytes.
"""

from __future__ import annotations

import math
from typing import Literal

import msgspec

from ramps.core.accelerators import parse_accelerator
from ramps.core.config import RampsConfig
from ramps.core.cost import NODE_CPU_MAX
from ramps.core.deadlines import ON_MISS

POLICIES = ("ramps", "paper", "round_robin", "random", "local_only")
FaultKind = Literal["crash", "network", "freeze", "recover", "load", "battery"]
FAULT_KINDS: tuple[FaultKind, ...] = ("crash", "network", "freeze", "recover", "load", "battery")


class ScenarioError(ValueError):
    """A scenario that cannot be run; ``path`` names the field at fault."""

    def __init__(self, path: str, message: str) -> None:
        super().__init__(f"{path}: {message}")
        self.path = path
        self.message = message


class _Spec(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    pass


class NetworkSpec(_Spec, frozen=True, kw_only=True, forbid_unknown_fields=True):
    #: one-way latency of every link, seconds
    latency: float = 0.005
    #: bandwidth of every link, bytes per second (20 Mbit/s WiFi)
    bandwidth: float = 2.5e6
    #: probability that any one message is lost
    loss: float = 0.0
    #: how long after a crash the teammates' transport notices (TCP reset)
    crash_detect: float = 0.01
    #: how long after a network cut or freeze the session lease expires
    #: (the node's default lease, NodeSettings.lease_ms = 2000)
    lease: float = 2.0
    #: whether liveliness (session-level failure notices) is used at all;
    #: the paper's prototype had only connection timeouts and heartbeats
    liveliness: bool = True


class PublisherSpec(_Spec, frozen=True, kw_only=True, forbid_unknown_fields=True):
    #: seconds between two load reports of one robot (paper: 2 s)
    period: float = 2.0
    #: CPU use in a report is averaged over this many seconds (paper: 1 s)
    window: float = 1.0


class RobotSpec(_Spec, frozen=True, kw_only=True, forbid_unknown_fields=True):
    #: robot name; with ``count`` it is a template such as ``"w{i}"`` (i from 1)
    name: str
    cores: int = 4
    speed: float = 1.0
    #: the speed the robot's node measured at boot, when it is wrong (robots
    #: booting together on a busy machine); default: ``speed``
    measured_speed: float | None = None
    #: CPU-bound processes that are not ramps programs (e.g. ``stress``)
    background: int = 0
    #: cores the robot's ramps node itself uses (its reports say so, and its
    #: programs share the rest when they fill the robot); 0: an ideal node
    node_cpu: float = 0.0
    #: niceness of the robot's ramps programs against that background (0:
    #: equal shares, the paper's world; a ramps node's default is 10, where
    #: a program gets about a tenth of what a busy process does)
    worker_nice: int = 0
    #: this robot's own link, when it is worse than the team's network: one-way
    #: latency (s) and bandwidth (bytes/s) of every message to or from it
    latency: float | None = None
    bandwidth: float | None = None
    #: at most this long (s) before its node handles a message it receives,
    #: drawn for each message, in the order received: a node on a throttled
    #: core (a cgroup quota) waits for its next share of it (0: at once)
    handling: float = 0.0
    #: free memory this robot reports, bytes (0: it reports none)
    memory: int = 0
    #: its node keeps a durable record of the programs it is origin of
    #: (``ramps.core.durable``): a crash followed by ``recover`` resumes them;
    #: without one a crashed origin's programs are lost (the paper's model)
    record: bool = False
    #: accelerators as ``KIND[:COUNT[:SPEED]]`` (``ramps.core.accelerators``),
    #: e.g. ``["cuda:1:20"]``: one slot running 20 work units a second
    accelerators: list[str] = []
    #: its battery's state of charge at the start, 0..1 (None: no battery),
    #: and the charge one busy core-second takes (``ramps.sim.battery``)
    battery: float | None = None
    drain: float = 0.0
    #: watts one busy core draws (None: not known; its energy counts 1 W)
    power: float | None = None
    #: expand this entry into ``count`` identical robots
    count: int | None = None


class ProgramSpec(_Spec, frozen=True, kw_only=True, forbid_unknown_fields=True):
    #: registered program name (weak mobility: every robot has the code)
    program: str = "route_plan"
    count: int = 1
    #: true amount of work of one program, in work units
    work: float = 53.0
    #: the work the program's declared profile claims (default: ``work``)
    work_estimate: float | None = None
    #: bytes of parameters sent when offloading, and of the result sent back
    payload: int = 1000
    result: int = 1000
    #: bytes of memory one program needs (0: not stated)
    memory: int = 0
    #: the robot that submits the programs
    origin: str
    #: submit time of the first program, and spacing between the next ones
    at: float = 0.0
    spacing: float = 0.0
    #: spacing is jittered by uniform(-jitter, +jitter) seconds
    jitter: float = 0.0
    #: a running program saves its state every this many seconds (0: never),
    #: so a move or a restart after a failure resumes from there
    #: (``ramps.checkpoint``); each checkpoint is ``checkpoint_size`` bytes
    checkpoint_every: float = 0.0
    checkpoint_size: int = 0
    #: each program's result is wanted this many seconds after it is
    #: submitted (None: no deadline); ``on_miss``: what its origin does when
    #: no robot is expected to make it: "run", "local" or "fail"
    deadline: float | None = None
    on_miss: str = "run"
    #: the kind of accelerator the program can use ("" = none), its true work
    #: there (default: ``work``) and what its profile declares (default: the
    #: true work), and whether it may run on a CPU where no robot has one
    accelerator: str = ""
    accelerator_work: float | None = None
    accelerator_estimate: float | None = None
    cpu_fallback: bool = True


class FaultSpec(_Spec, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """Something that happens to a robot at ``at``: a fault, a recovery, or
    (``load``) its own software changing how many CPU-bound processes it
    runs to ``background`` (e.g. a heavy job starting after placement), or
    (``battery``) its battery's charge becoming ``charge``."""

    at: float
    robot: str
    kind: FaultKind
    #: ``load`` only: the robot's busy processes from then on
    background: int | None = None
    #: ``battery`` only: the robot's state of charge from then on, 0..1
    charge: float | None = None


class Scenario(_Spec, frozen=True, kw_only=True, forbid_unknown_fields=True):
    robots: list[RobotSpec]
    programs: list[ProgramSpec]
    name: str = "scenario"
    seed: int = 0
    policy: str = "ramps"
    faults: list[FaultSpec] = []
    network: NetworkSpec = NetworkSpec()
    publisher: PublisherSpec = PublisherSpec()
    config: RampsConfig = RampsConfig()
    #: robots run this long before the first program, so load views are warm
    warmup: float = 5.0
    #: stop the simulation at this virtual time even if programs remain
    until: float | None = None

    def team(self) -> list[RobotSpec]:
        """The robots with every ``count`` template expanded."""
        out: list[RobotSpec] = []
        for spec in self.robots:
            if spec.count is None:
                out.append(spec)
            else:
                for i in range(1, spec.count + 1):
                    out.append(msgspec.structs.replace(spec, name=spec.name.format(i=i), count=None))
        return out

    def check(self) -> "Scenario":
        """Semantic checks beyond types; raises ScenarioError. Returns self."""
        if not self.robots:
            raise ScenarioError("$.robots", "a team needs at least one robot")
        for i, r in enumerate(self.robots):
            _check_robot(f"$.robots[{i}]", r)
        seen: dict[str, int] = {}
        for r in self.team():
            if r.name in seen:
                idx = next(i for i, s in enumerate(self.robots) if s.name == r.name or (s.count and "{i}" in s.name))
                raise ScenarioError(f"$.robots[{idx}].name", f"robot name {r.name!r} is used twice")
            seen[r.name] = 1
        if not self.programs:
            raise ScenarioError("$.programs", "a workload needs at least one program entry")
        for i, spec in enumerate(self.programs):
            _check_program(f"$.programs[{i}]", spec, seen)
        for i, f in enumerate(self.faults):
            if f.robot not in seen:
                raise ScenarioError(f"$.faults[{i}].robot", f"unknown robot {f.robot!r}")
            if f.at < 0:
                raise ScenarioError(f"$.faults[{i}].at", f"must be >= 0, got {f.at}")
            if f.kind == "load" and (f.background is None or f.background < 0):
                raise ScenarioError(f"$.faults[{i}].background",
                                    f"a load change needs background >= 0 (busy processes), got {f.background}")
            if f.kind != "load" and f.background is not None:
                raise ScenarioError(f"$.faults[{i}].background", f"only a 'load' change sets background, not {f.kind!r}")
            if (f.kind == "battery") != (f.charge is not None) or not 0.0 <= (f.charge or 0.0) <= 1.0:
                raise ScenarioError(f"$.faults[{i}].charge", f"a 'battery' change, and it only, sets a charge 0..1, "
                                                             f"got {f.charge!r} for {f.kind!r}")
        if self.policy not in POLICIES:
            raise ScenarioError("$.policy", f"unknown policy {self.policy!r}; choose one of {', '.join(POLICIES)}")
        n = self.network
        if n.latency < 0 or not n.bandwidth > 0 or not 0 <= n.loss < 1:
            raise ScenarioError("$.network", "latency >= 0, bandwidth > 0 and 0 <= loss < 1 are required")
        if not self.publisher.period > 0 or not 0 < self.publisher.window <= self.publisher.period:
            raise ScenarioError("$.publisher", "period > 0 and 0 < window <= period are required")
        if self.warmup < 0:
            raise ScenarioError("$.warmup", f"must be >= 0, got {self.warmup}")
        return self


def _check_robot(p: str, r: RobotSpec) -> None:
    """``Scenario.check`` of one robot entry at path ``p``."""
    if not r.name:
        raise ScenarioError(f"{p}.name", "must not be empty")
    if r.cores < 1:
        raise ScenarioError(f"{p}.cores", f"must be >= 1, got {r.cores}")
    if not r.speed > 0:
        raise ScenarioError(f"{p}.speed", f"must be > 0, got {r.speed}")
    if r.measured_speed is not None and not r.measured_speed > 0:
        raise ScenarioError(f"{p}.measured_speed", f"must be > 0, got {r.measured_speed}")
    if r.background < 0:
        raise ScenarioError(f"{p}.background", f"must be >= 0, got {r.background}")
    if r.battery is not None and not 0.0 <= r.battery <= 1.0:
        raise ScenarioError(f"{p}.battery", f"must be a state of charge 0..1, got {r.battery}")
    if not 0.0 <= r.drain <= 1.0 or (r.power is not None and not 0.0 < r.power <= 1e9):
        raise ScenarioError(f"{p}.{'drain' if not 0.0 <= r.drain <= 1.0 else 'power'}",
                            f"drain is 0..1 a busy core-second, power watts > 0; got {r.drain}, {r.power}")
    if not 0.0 <= r.node_cpu <= NODE_CPU_MAX * r.cores:
        raise ScenarioError(f"{p}.node_cpu", f"must be between 0 and half the robot's cores, got {r.node_cpu}")
    if not -20 <= r.worker_nice <= 19:
        raise ScenarioError(f"{p}.worker_nice", f"must be -20..19 (a Linux niceness), got {r.worker_nice}")
    if r.latency is not None and not r.latency >= 0:
        raise ScenarioError(f"{p}.latency", f"must be >= 0, got {r.latency}")
    if not r.handling >= 0:
        raise ScenarioError(f"{p}.handling", f"must be >= 0, got {r.handling}")
    if r.bandwidth is not None and not r.bandwidth > 0:
        raise ScenarioError(f"{p}.bandwidth", f"must be > 0, got {r.bandwidth}")
    if r.memory < 0:
        raise ScenarioError(f"{p}.memory", f"must be >= 0, got {r.memory}")
    for j, text in enumerate(r.accelerators):
        try:
            parse_accelerator(text)
        except ValueError as exc:
            raise ScenarioError(f"{p}.accelerators[{j}]", str(exc)) from None
    if r.count is not None:
        if r.count < 1:
            raise ScenarioError(f"{p}.count", f"must be >= 1, got {r.count}")
        if "{i}" not in r.name:
            raise ScenarioError(f"{p}.name", "with count, the name must contain {i}, e.g. 'w{i}'")


def _check_program(path: str, spec: ProgramSpec, seen: dict[str, int]) -> None:
    """``Scenario.check`` of one program entry at ``path`` (``seen``: the robots)."""
    if spec.origin not in seen:
        raise ScenarioError(f"{path}.origin", f"unknown robot {spec.origin!r}")
    if spec.count < 1:
        raise ScenarioError(f"{path}.count", f"must be >= 1, got {spec.count}")
    if not spec.work > 0:
        raise ScenarioError(f"{path}.work", f"must be > 0, got {spec.work}")
    if spec.work_estimate is not None and not spec.work_estimate > 0:
        raise ScenarioError(f"{path}.work_estimate", f"must be > 0, got {spec.work_estimate}")
    for fld in ("payload", "result", "at", "spacing", "jitter", "memory", "checkpoint_every",
                "checkpoint_size"):
        if getattr(spec, fld) < 0:
            raise ScenarioError(f"{path}.{fld}", f"must be >= 0, got {getattr(spec, fld)}")
    if spec.deadline is not None and not (math.isfinite(spec.deadline) and spec.deadline > 0):
        raise ScenarioError(f"{path}.deadline", f"must be > 0 seconds, got {spec.deadline}")
    if spec.on_miss not in ON_MISS:
        raise ScenarioError(f"{path}.on_miss", f"must be one of {', '.join(ON_MISS)}, got {spec.on_miss!r}")
    for fld in ("accelerator_work", "accelerator_estimate"):
        value = getattr(spec, fld)
        if value is not None and not (math.isfinite(value) and value > 0):
            raise ScenarioError(f"{path}.{fld}", f"must be > 0, got {value}")
    if not spec.cpu_fallback and not spec.accelerator:
        raise ScenarioError(f"{path}.cpu_fallback", "false needs an accelerator kind")
