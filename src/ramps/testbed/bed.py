"""``Testbed``: emulated robots on one Linux host, with fault injection.

How this works: each robot is

* a network namespace ``ramps-<tb>-<robot>`` with one veth (``eth0``) on the
  testbed's bridge (``ramps.testbed.net``: addresses, multicast, cutting),
* a cpu cgroup of the same name (``RobotCgroup`` from
  ``ramps.runtime.localteam``, v1 or v2) whose quota makes it a small
  computer of ``quota`` host cores (default: host cores / robots),
* a ``python -m ramps.cli node`` listening on ``tcp/<robot ip>:7447`` in
  that namespace and cgroup, in its own session (its workers share its
  process group), plus optional background load: busy processes in the
  same namespace and cgroup (the paper's ``stress``).

Discovery: multicast scouting (``--multicast``) inside the bridge *and* an
explicit ``--connect`` to a seed, r1, which every other robot dials and
which dials nobody. Multicast alone finds everyone at start-up; the seed
makes rejoining after a cut deterministic (the side holding a ``connect``
endpoint redials by itself: docs/lab/2026-11-23-failures.md, zenoh#2806)
instead of depending on the scouting period. ``discovery="multicast"`` or
``"connect"`` picks just one of the two.

This module builds a testbed and takes it down, tells its nodes what to
run, writes its state file, waits for its team and reports its status.
A ``Testbed`` holds its parts: ``procs`` (``ramps.testbed.robots``: the
robots' processes), ``faults`` (``ramps.testbed.faults``: crash, cut,
lossy, freeze, load, restart, offered as its own methods) and taking it
down at exit (``ramps.testbed.exits``); ``ramps.testbed.sessions`` opens
Zenoh sessions on its team, ``ramps.testbed.cleanup`` clears a host of
testbeds (``down_all``, ``leftovers``).

State: every testbed writes ``/run/ramps/testbed-<tb>.json`` (robots, IPs,
namespaces, cgroups, pids with their start times, faults), so ``ramps
testbed up`` can leave it running and ``Testbed.attach()`` (the other CLI
commands) can act on it from another process. Pids are checked against
their start time, so a reused pid is never signalled.

Rules: root only; ``PermissionError("the testbed needs root: ...")`` is
raised before anything is created. ``down()`` removes everything this
testbed made (processes, cgroups, namespaces and veths, bridge, state
file); it runs on leaving the ``with`` block (exception or not), on
SIGINT/SIGTERM of the creating process and at interpreter exit (unless
``detach()`` was called), and a second call does nothing. The testbed id
(``t<X>``, subnet ``10.201.X.0/24``) is reserved by creating its state file
exclusively, so testbeds started at once by parallel processes (pytest-xdist
workers) never take the same one.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ramps.errors import NoTeam
from ramps.runtime.accelerators import remove_slot_folders
from ramps.runtime.localteam import RobotCgroup, cgroup_mode, partial_views
from ramps.testbed import net
from ramps.testbed.exits import DownOnExit
from ramps.testbed.faults import Faults
from ramps.testbed.procs import RobotRecord, TestbedError, _cgroup, robot_record
from ramps.testbed.robots import PORT, STATE_DIR, RobotProcesses, check_config, check_robots, node_config_file
from ramps.testbed.sessions import open_watcher, root_config, team_client

if TYPE_CHECKING:
    import zenoh

    from ramps.runtime.watch import TeamWatcher

FAULTS = ("crashed", "cut", "frozen", "lossy")

__all__ = ["FAULTS", "PORT", "STATE_DIR", "DidNotJoin", "Testbed", "watch_team"]


class DidNotJoin(NoTeam):
    """The nodes run but did not all join the team in time (``Testbed.wait_alive``)."""


class Testbed:
    """Emulated robots on this host; see the module docstring.

    >>> with Testbed(3, lease_ms=1000) as tb:
    ...     team = tb.client("r1")
    ...     print(team.submit("burn", seconds=0.2).result())
    ...     tb.cut("r2"); ...; tb.recover("r2")
    """

    __test__ = False

    def __init__(self, robots: int | list[str] = 5, *, team: str | None = None, quota: float | None = None,
                 cores: int | None = None, speed: float | None = None, programs: list[str] | None = None,
                 lease_ms: int | None = None, policy: str | None = None, loaded: dict[str, int] | None = None,
                 discovery: str = "both", caps: bool = True, python: str | None = None,
                 state_dir: Path | None = None, config: Mapping[str, Any] | None = None,
                 robot_config: Mapping[str, Mapping[str, Any]] | None = None, period_us: int = 100_000) -> None:
        net.need_root()
        mode = cgroup_mode()
        if mode is None:
            raise PermissionError("the testbed needs root and writable cpu cgroups (v1 /sys/fs/cgroup/cpu or v2)")
        self.mode = mode
        names = check_robots(robots, discovery, loaded or {}, robot_config or {})
        host_cores = len(os.sched_getaffinity(0))
        self.quota = float(quota) if quota is not None else round(max(0.05, host_cores / len(names)), 3)
        if not self.quota > 0:
            raise ValueError(f"quota must be > 0 host cores, got {quota}")
        self.names, self.team_name, self.period_us = names, team, int(period_us)  # period: RobotCgroup
        self.cores: int | None = cores
        self.speed: float | None = speed
        self.policy: str | None = policy
        self.lease_ms: int | None = lease_ms
        self.programs = list(programs or [])
        #: every node's config file, as a dict: node settings, and RampsConfig fields under "core",
        #: e.g. {"worker_nice": 0, "core": {"relocate": False}}
        self.config = check_config(config or {})
        #: settings of some robots' nodes over ``config``, e.g. {"r4": {"accelerators": ["cuda:1:20:emulated"]}}
        self.robot_config = {r: check_config(c) for r, c in (robot_config or {}).items()}
        self.discovery = discovery
        #: per-program CPU caps (ramps.testbed.caps; cgroup v1 only)
        self.caps = caps and self.mode == "v1"
        self.python = python or sys.executable
        self.state_dir = Path(state_dir or STATE_DIR)
        self.loaded = dict(loaded or {})
        self._popen: dict[int, subprocess.Popen[bytes]] = {}
        self._lock = threading.RLock()
        self.robots: dict[str, RobotRecord] = {}
        self._not_made()
        self._attached = False
        self._parts()

    def _parts(self) -> None:
        """The robots' processes, their faults and taking it down at exit, given what they use of it."""
        self.procs = RobotProcesses(self.robots, self.mode, self.python, self._popen)
        self.faults = Faults(self, self.procs, self._lock)
        self._on_exit = DownOnExit(self.down)

    # ------------------------------------------------------------ attach (another process)
    @classmethod
    def attach(cls, tb: str | None = None, *, state_dir: Path | None = None) -> "Testbed":
        """The testbed ``tb`` (default: the only one up) from its state file."""
        if os.geteuid() != 0:
            raise PermissionError("the testbed needs root: its namespaces and cgroups belong to root")
        d = Path(state_dir or STATE_DIR)
        files = sorted(d.glob("testbed-*.json"))
        if tb is not None:
            files = [f for f in files if f.stem == f"testbed-{tb}"]
        if not files:
            raise TestbedError("no testbed is up" + (f" with id {tb!r}" if tb else "") +
                               "; start one with `ramps testbed up`")
        if len(files) > 1:
            ids = ", ".join(f.stem.removeprefix("testbed-") for f in files)
            raise TestbedError(f"several testbeds are up ({ids}); pick one with --tb")
        st = json.loads(files[0].read_text())
        self = cls.__new__(cls)
        self.names = [r["name"] for r in st["robots"]]
        self.robots = {r["name"]: robot_record(r) for r in st["robots"]}
        self.tb, self.x, self.quota, self.mode = st["tb"], st["x"], st["quota"], st["mode"]
        self.cores, self.speed, self.policy, self.lease_ms = st["cores"], st["speed"], st["policy"], st["lease_ms"]
        self.programs, self.discovery, self.python, self.loaded = st["programs"], st["discovery"], st["python"], st["loaded"]
        self.caps, self.caps_pid = st.get("caps", False), st.get("caps_pid", [None, None])
        self.config = st.get("config", {})
        self.robot_config = st.get("robot_config", {})
        self.team_name = st["team"]
        self.log_dir = Path(st["log_dir"]) if st.get("log_dir") else None
        self.state_dir = d
        self._popen, self._lock = {}, threading.RLock()
        self._created, self._down, self._attached = True, False, True
        self._parts()
        return self

    # ------------------------------------------------------------ names
    @property
    def team(self) -> str:
        return self.team_name or f"tb-{self.tb}"

    def ip(self, robot: str) -> str:
        return self._robot(robot)["ip"]

    def endpoint(self, robot: str) -> str:
        return f"tcp/{self.ip(robot)}:{PORT}"

    def endpoints(self) -> list[str]:
        return [self.endpoint(r) for r in self.names]

    def namespace(self, robot: str) -> str:
        return self._robot(robot)["ns"]

    def _robot(self, robot: str) -> RobotRecord:
        return self.procs.record(robot)

    # ------------------------------------------------------------ the nodes and the state file
    @property
    def state_file(self) -> Path:
        """``<state dir>/testbed-<tb>.json``: what ``Testbed.attach`` reads."""
        return self.state_dir / f"testbed-{self.tb}.json"

    @property
    def records_dir(self) -> Path:
        """Where the robots' nodes keep their durable records (``ramps.runtime.store``)."""
        return self.state_dir / f"records-{self.tb}"

    def _save(self) -> None:
        """Write the state file whole (a temporary file, renamed over it): a reader never sees half of it."""
        st = dict(tb=self.tb, x=self.x, team=self.team, quota=self.quota, cores=self.cores, speed=self.speed,
                  policy=self.policy, lease_ms=self.lease_ms, programs=self.programs, discovery=self.discovery,
                  python=self.python, mode=self.mode, loaded=self.loaded, caps=self.caps, caps_pid=self.caps_pid,
                  config=self.config, robot_config=self.robot_config,
                  log_dir=str(self.log_dir) if self.log_dir else None, created_by=os.getpid(),
                  robots=[self.robots[r] for r in self.names if r in self.robots])
        tmp = self.state_file.with_suffix(".tmp")
        tmp.write_text(json.dumps(st, indent=1))
        tmp.replace(self.state_file)

    def _node_cmd(self, robot: str) -> list[str]:
        """The robot's node: ``tcp/<robot ip>:7447``; unless ``discovery="multicast"`` every robot
        but the first dials the first (the seed); unless ``"connect"`` they also scout by multicast."""
        rb = self.robots[robot]
        cmd = [self.python, "-m", "ramps.cli", "node", "--robot", robot, "--team", self.team,
               "--listen", f"tcp/{rb['ip']}:{PORT}"]
        if self.discovery in ("both", "connect") and robot != self.names[0]:
            cmd += ["--connect", f"tcp/{self.robots[self.names[0]]['ip']}:{PORT}"]
        cmd += ["--multicast" if self.discovery in ("both", "multicast") else "--no-multicast"]
        cmd += ["--no-battery-sysfs"]  # the host's battery is no robot's (a battery_file in config still counts)
        return cmd + self._node_options(robot)

    def _node_options(self, robot: str) -> list[str]:
        """What every robot's node is told whatever its network: cores, speed,
        policy, lease, programs, config file, trace and durable record."""
        cmd: list[str] = []
        for flag, value in (("--cores", self.cores), ("--speed", self.speed), ("--policy", self.policy),
                            ("--lease-ms", self.lease_ms)):
            if value is not None:
                cmd += [flag, str(value)]
        for p in self.programs:
            cmd += ["--program", p]
        if (self.config or self.robot_config.get(robot)) and self.log_dir:
            cmd += ["--config", str(node_config_file(self.log_dir, robot, self.config, self.robot_config))]
        if self.log_dir:  # every decision, for experiments and post-mortems: <log_dir>/<robot>.trace.jsonl
            cmd += ["--trace", str(self.log_dir / f"{robot}.trace.jsonl")]
        cmd += ["--state-dir", str(self.records_dir)]  # each robot's durable record, removed with the testbed
        return cmd

    def _start_node(self, robot: str) -> None:
        rb = self.robots[robot]
        log = self.log_dir / f"{robot}.log" if self.log_dir else None
        rb["pid"], rb["start"] = self.procs.spawn(robot, self._node_cmd(robot), log)

    def _spawn(self, robot: str, argv: list[str], log: Path | None) -> tuple[int, int | None]:
        return self.procs.spawn(robot, argv, log)  # another program beside the robot's node

    def log_tail(self, robot: str, lines: int = 15) -> str:
        if self.log_dir is None:
            return "(no log)"
        try:
            return "\n".join((self.log_dir / f"{robot}.log").read_text(errors="replace").splitlines()[-lines:])
        except OSError:
            return "(no log)"

    # ------------------------------------------------------------ faults (ramps.testbed.faults)
    def process_state(self, robot: str) -> str:
        """'running', 'stopped' or 'dead' of the robot's node."""
        return self.procs.state(robot)

    def crash(self, robot: str) -> None:
        """SIGKILL the robot's node, workers and load (a power cut)."""
        self.faults.crash(robot)

    def cut(self, robot: str) -> None:
        """Take the robot's network link down; its processes keep running."""
        self.faults.cut(robot)

    def lossy(self, robot: str, loss: float) -> None:
        """Drop each of the robot's packets, in and out, with probability ``loss``."""
        self.faults.lossy(robot, loss)

    def freeze(self, robot: str) -> None:
        """SIGSTOP every process of the robot."""
        self.faults.freeze(robot)

    def recover(self, robot: str, *, wait: bool = True, timeout: float = 30.0) -> list[str]:
        """Undo every fault of the robot; the faults undone (``Faults.recover``)."""
        return self.faults.recover(robot, wait=wait, timeout=timeout)

    def add_load(self, robot: str, n: int = 1) -> None:
        """Start ``n`` busy processes inside the robot."""
        self.faults.add_load(robot, n)

    def remove_load(self, robot: str) -> None:
        self.faults.remove_load(robot)

    def restart(self, robot: str, *, timeout: float = 30.0) -> float:
        """Restart the robot's node as its supervisor does; seconds until it is back (``Faults.restart``)."""
        return self.faults.restart(robot, timeout=timeout)

    def _live(self) -> None:
        if not self._created or self._down:
            raise TestbedError("this testbed is not up")

    # ------------------------------------------------------------ up
    def up(self, timeout: float = 60.0, tries: int = 2) -> "Testbed":
        """Build the network and cgroups, start every node, wait until all are alive.

        When the robots do not all join within ``timeout`` (a busy host: seen
        about once in six testbeds started one after another), the testbed is
        taken down and made again, up to ``tries`` times in all. A node that
        exits at start is not retried: its log says why (NoTeam)."""
        if self._created:
            return self
        for attempt in range(1, tries + 1):
            try:
                return self._up_once(timeout)
            except DidNotJoin as exc:
                if attempt >= tries:
                    raise
                print(f"testbed: {str(exc).splitlines()[0]}; starting it again ({attempt + 1} of {tries})",
                      file=sys.stderr, flush=True)
                self._not_made()
        raise AssertionError("unreachable")

    def _not_made(self) -> None:
        """What a testbed not made yet holds (at construction, and before ``up`` tries again)."""
        self.tb: str | None = None
        self.x = 0
        self.robots.clear()  # cleared, not replaced: the parts hold this dict
        self.log_dir: Path | None = None
        self.caps_pid: list[int | None] = [None, None]  # the capper: pid, start time
        self._created = False
        self._down = False

    def _up_once(self, timeout: float) -> "Testbed":
        self._on_exit.install()
        try:
            with self._lock:
                self._created = True
                self.state_dir.mkdir(parents=True, exist_ok=True)
                taken = {int(m.group(1)) for f in self.state_dir.glob("testbed-t*.json")
                         if (m := re.fullmatch(r"testbed-t(\d+)", f.stem))}
                while True:  # reserve the id by creating its state file: a parallel testbed picking it too skips it
                    self.x = net.free_subnet(taken)
                    self.tb = f"t{self.x}"
                    try:
                        with open(self.state_file, "x"):
                            break
                    except FileExistsError:
                        taken.add(self.x)
                self.log_dir = Path(tempfile.mkdtemp(prefix=f"ramps-testbed-{self.tb}-"))
                for i, r in enumerate(self.names, 1):
                    ns = net.ns_name(self.tb, r)
                    self.robots[r] = RobotRecord(name=r, index=i, ip=net.robot_ip(self.x, i), ns=ns,
                                                 veth=net.veth_name(self.tb, r), cgroup=[], pid=None, start=None,
                                                 load=self.loaded.get(r, 0), load_pids=[], faults=[])
                self._save()  # from here on, down_all() finds it even if we die
                net.make_bridge(self.tb, self.x)
                for r in self.names:
                    rb = self.robots[r]
                    net.make_robot(self.tb, self.x, rb["index"], r)
                    cg = RobotCgroup(rb["ns"], self.quota, self.mode, self.period_us)
                    rb["cgroup"] = [str(d) for d in cg.dirs]
                    self._save()
                for r in self.names:
                    self._start_node(r)
                    self.procs.start_load(r, self.robots[r]["load"])
                self._save()
                if self.caps:  # one process for the testbed (ramps.testbed.caps); it ends with the state file
                    log = self.log_dir / "caps.log" if self.log_dir else None
                    self.caps_pid = self.procs.spawn_root([self.python, "-m", "ramps.testbed.caps",
                                                           str(self.state_file)], log)
                    self._save()
            self.wait_alive(self.names, timeout)
        except BaseException:
            self.down()
            raise
        return self

    def wait_alive(self, robots: list[str] | None = None, timeout: float = 60.0) -> float:
        """Wait until ``robots`` (default all) are alive in the team and publish their load, seen
        from the root namespace, and each sees all the others; the seconds it took. NoTeam (their
        logs' tails) when a node exits, DidNotJoin when they do not all join within ``timeout``."""
        robots = list(robots or self.names)
        t0 = time.monotonic()
        deadline = t0 + timeout
        with watch_team(self, redial=True) as obs:  # opened before the nodes listen: dial them again soon
            while True:
                for r in robots:
                    if self.process_state(r) == "dead":
                        raise NoTeam(f"the node of robot {r} exited at start:\n{self.log_tail(r)}")
                # ready: alive (liveliness token) and publishing load (a report since we started looking),
                # and every ready robot counts all the others as candidates in its own view
                ready = obs.ready()
                blind: dict[str, int | None] = {}
                if set(robots) <= ready:
                    sees = {r: rep.sees for r in sorted(ready) if (rep := obs.report(r)) is not None}
                    blind = partial_views(sees, len(ready))
                    if not blind:
                        return time.monotonic() - t0
                if time.monotonic() > deadline:
                    tails = "\n".join(f"--- {r}:\n{self.log_tail(r)}" for r in robots)
                    seeing = f" (robots that do not see all {len(ready) - 1} others: {blind})" if blind else ""
                    raise DidNotJoin(f"robots {', '.join(robots)} did not all join team {self.team} within "
                                 f"{timeout:g} s{seeing}\n{tails}")
                time.sleep(0.05)

    # ------------------------------------------------------------ clients
    def client(self, robot: str = "r1", *, timeout: float = 10.0, lease_ms: int | None = None,
               **options: Any) -> Any:  # a Team: typed so, mypy cannot infer callers' lambdas with defaults
        """A ``ramps.runtime.client.Team`` in the root namespace, connected to
        every robot over the bridge, whose programs start on ``robot``
        (``options``: more of ``Team``'s, e.g. ``origin_grace``)."""
        self._robot(robot)
        return team_client(self.team, robot, {"connect": self.endpoints()}, timeout=timeout, lease_ms=lease_ms,
                           **options)

    def zenoh_config(self) -> zenoh.Config:
        """A plain Zenoh peer config for the root namespace (connects to every robot)."""
        return root_config("peer", self.endpoints())

    # ------------------------------------------------------------ looking
    def status(self, *, team_view: bool = False, timeout: float = 2.0) -> dict[str, Any]:
        """Per robot: namespace present, link state, node process state, load,
        faults; with ``team_view``, the team as a client in the root namespace sees it."""
        if self.tb is None:
            raise TestbedError("the testbed is not up")
        have_ns = set(net.namespaces())
        robots = [self.procs.status(r, have_ns) for r in self.names]
        out: dict[str, Any] = dict(tb=self.tb, team=self.team, subnet=f"{net.SUBNET_BASE}.{self.x}.0/24",
                                   bridge=net.bridge_name(self.tb), quota=self.quota, cgroups=self.mode,
                                   robots=robots, connect=self.endpoints())
        if team_view:
            try:
                with watch_team(self) as obs:
                    deadline = time.monotonic() + timeout  # let liveliness and load reports arrive
                    want = {r["robot"] for r in robots if r["process"] == "running" and r["link"] == "up"}
                    while time.monotonic() < deadline and not want <= obs.ready():
                        time.sleep(0.05)
                    out["team_view"] = obs.view()
            except Exception as exc:  # a Zenoh error: report it, the rest of the status stands
                out["team_view_error"] = f"no team view: {exc}"
        return out

    # ------------------------------------------------------------ down
    def down(self) -> None:
        """Remove everything this testbed made; harmless when already down."""
        with self._lock:
            if self._down or not self._created:
                self._down = True
                self._on_exit.release()
                return
            self._down = True
            try:
                self.procs.stop(*self.caps_pid)  # before the robots: it would make cgroups as they go
                self.caps_pid = [None, None]
                for r in self.names:
                    if r in self.robots:
                        self.procs.kill(r)
                for r in self.names:
                    rb = self.robots.get(r)
                    if rb and rb["cgroup"]:
                        _cgroup(rb["cgroup"], self.mode).remove()
                if self.tb:
                    net.remove(self.tb, self.names)
                self.procs.wait_all()
                if self.log_dir:
                    shutil.rmtree(self.log_dir, ignore_errors=True)
                remove_slot_folders(self.team)  # emulated accelerators' (their nodes were killed)
                if self.tb:
                    shutil.rmtree(self.records_dir, ignore_errors=True)
                    self.state_file.unlink(missing_ok=True)
                    self.state_file.with_suffix(".tmp").unlink(missing_ok=True)
                    try:
                        self.state_dir.rmdir()  # only when no other testbed is up
                    except OSError:
                        pass
            finally:
                self._on_exit.release()

    def detach(self) -> None:
        """Leave the testbed running after this process exits (``ramps testbed up``)."""
        self._on_exit.release()
        self._popen.clear()  # not ours to reap any more

    def __enter__(self) -> "Testbed":
        return self.up()

    def __exit__(self, *exc: object) -> None:
        self.down()


def watch_team(testbed: Testbed, *, redial: bool = False) -> TeamWatcher:
    """A ``TeamWatcher`` of the testbed's team in the root namespace, on its
    ``zenoh_config`` (``ramps.testbed.sessions.open_watcher``: ``redial``)."""
    return open_watcher(testbed.zenoh_config(), testbed.team, redial=redial)
