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

The testbed is five modules, by concern: this one builds a testbed and
takes it down (its lifecycle), waits for its team and reports its status;
``ramps.testbed.robots`` starts the robots' processes and writes the state
file; ``ramps.testbed.faults`` breaks and mends robots (crash, cut, lossy,
freeze, load); ``Testbed`` inherits the methods of both.
``ramps.testbed.cleanup`` clears a host of testbeds, including those of
crashed runs (``down_all``, ``leftovers``); ``ramps.testbed.procs`` holds
the pid and cgroup helpers they share.

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

import atexit
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from types import FrameType
from typing import TYPE_CHECKING, Any

from ramps.errors import NoTeam
from ramps.runtime.accelerators import remove_slot_folders
from ramps.runtime.localteam import RobotCgroup, cgroup_mode, partial_views
from ramps.testbed import net
from ramps.testbed.faults import Faults
from ramps.testbed.procs import RobotRecord, TestbedError, _alive, _cgroup, robot_record
from ramps.testbed.robots import PORT, STATE_DIR, Robots, _check_config

if TYPE_CHECKING:
    import zenoh

    from ramps.runtime.watch import TeamWatcher

FAULTS = ("crashed", "cut", "frozen", "lossy")

__all__ = ["FAULTS", "PORT", "STATE_DIR", "DidNotJoin", "Testbed", "watch_team"]

#: a signal's handler as ``signal.getsignal`` returns it
_Handler = Callable[[int, FrameType | None], Any] | int | signal.Handlers | None


class DidNotJoin(NoTeam):
    """The nodes run but did not all join the team in time (``Testbed.wait_alive``)."""


# ====================================================================== the testbed
class Testbed(Robots, Faults):
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
                 robot_config: Mapping[str, Mapping[str, Any]] | None = None) -> None:
        net.need_root()
        mode = cgroup_mode()
        if mode is None:
            raise PermissionError("the testbed needs root and writable cpu cgroups (v1 /sys/fs/cgroup/cpu or v2)")
        self.mode = mode
        names = [f"r{i}" for i in range(1, robots + 1)] if isinstance(robots, int) else list(robots)
        if not names:
            raise ValueError("a testbed needs at least one robot")
        if discovery not in ("both", "multicast", "connect"):
            raise ValueError("discovery must be both, multicast or connect")
        net.check_names("t250", names)
        for r in loaded or {}:
            if r not in names:
                raise ValueError(f"loaded robot {r!r} is not one of {', '.join(names)}")
        host_cores = len(os.sched_getaffinity(0))
        self.quota = float(quota) if quota is not None else round(max(0.05, host_cores / len(names)), 3)
        if not self.quota > 0:
            raise ValueError(f"quota must be > 0 host cores, got {quota}")
        self.names = names
        self.team_name = team
        self.cores: int | None = cores
        self.speed: float | None = speed
        self.policy: str | None = policy
        self.lease_ms: int | None = lease_ms
        self.programs = list(programs or [])
        #: every node's config file, as a dict: node settings, and RampsConfig fields under "core",
        #: e.g. {"worker_nice": 0, "core": {"relocate": False}}
        self.config = _check_config(config or {})
        #: settings of some robots' nodes over ``config``, e.g. {"r4": {"accelerators": ["cuda:1:20:emulated"]}}
        self.robot_config = {r: _check_config(c) for r, c in (robot_config or {}).items()}
        for r in self.robot_config:
            if r not in names:
                raise ValueError(f"robot_config names {r!r}, not one of {', '.join(names)}")
        self.discovery = discovery
        #: per-program CPU caps (ramps.testbed.caps; cgroup v1 only for now)
        self.caps = caps and self.mode == "v1"
        self.python = python or sys.executable
        self.state_dir = Path(state_dir or STATE_DIR)
        self.loaded = dict(loaded or {})
        self._popen: dict[int, subprocess.Popen[bytes]] = {}
        self._lock = threading.RLock()
        self._not_made()
        self._attached = False
        self._old_handlers: dict[int, _Handler] = {}
        self._atexit = False

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
        self._old_handlers, self._atexit = {}, False
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
        if robot not in self.robots:
            raise TestbedError(f"unknown robot {robot!r}; this testbed has {', '.join(self.names)}")
        return self.robots[robot]

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
        self.robots: dict[str, RobotRecord] = {}
        self.log_dir: Path | None = None
        self.caps_pid: list[int | None] = [None, None]  # the capper: pid, start time
        self._created = False
        self._down = False

    def _up_once(self, timeout: float) -> "Testbed":
        self._install_handlers()
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
                    cg = RobotCgroup(rb["ns"], self.quota, self.mode)
                    rb["cgroup"] = [str(d) for d in cg.dirs]
                    self._save()
                for r in self.names:
                    self._start_node(r)
                    self._start_load(r, self.robots[r]["load"])
                self._save()
                if self.caps:
                    self._start_caps()
            self.wait_alive(self.names, timeout)
        except BaseException:
            self.down()
            raise
        return self

    def wait_alive(self, robots: list[str] | None = None, timeout: float = 60.0) -> float:
        """Wait until ``robots`` (default all) are alive in the team and publish
        their load, seen from the root namespace, and every robot that does
        sees all the others; return the seconds it took.
        Raises NoTeam with the tail of their logs."""
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
        from ramps.runtime.client import Team
        from ramps.runtime.settings import load_settings

        self._robot(robot)
        flags: dict[str, object] = {"team": self.team, "connect": self.endpoints(), "multicast": False, "listen": [],
                 "shared_memory": False}
        if lease_ms is not None:
            flags["lease_ms"] = lease_ms
        s = load_settings(flags=flags, default_robot=False, environ={})
        return Team(s, robot=robot, timeout=timeout, **options)

    def zenoh_config(self) -> zenoh.Config:
        """A plain Zenoh peer config for the root namespace (connects to every robot)."""
        import zenoh

        from ramps.runtime.zenoh_configs import zenoh_runtime_defaults

        zenoh_runtime_defaults()  # a lost robot must not make the observer deaf either
        c = zenoh.Config()
        c.insert_json5("mode", '"peer"')
        c.insert_json5("listen/endpoints", "[]")
        c.insert_json5("connect/endpoints", json.dumps(self.endpoints()))
        c.insert_json5("scouting/multicast/enabled", "false")
        c.insert_json5("transport/shared_memory/enabled", "false")  # as the robots (_spawn)
        return c

    # ------------------------------------------------------------ looking
    def status(self, *, team_view: bool = False, timeout: float = 2.0) -> dict[str, Any]:
        """Per robot: namespace present, link state, node process state, load,
        faults; with ``team_view``, the team as a client in the root namespace sees it."""
        if self.tb is None:
            raise TestbedError("the testbed is not up")
        have_ns = set(net.namespaces())
        robots = []
        for r in self.names:
            rb = self.robots[r]
            ns_ok = rb["ns"] in have_ns
            loads = sum(1 for p, s in rb["load_pids"] if _alive(p, s) != "dead")
            robots.append(dict(robot=r, ip=rb["ip"], namespace=rb["ns"] if ns_ok else None,
                               link=net.link_state(rb["ns"]) if ns_ok else "missing",
                               process=self.process_state(r), pid=rb["pid"], load=rb["load"],
                               load_running=loads, faults=list(rb["faults"])))
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
                self._restore_handlers()
                return
            self._down = True
            try:
                self._stop_caps()  # before the robots: it would make cgroups as they go
                for r in self.names:
                    if r in self.robots:
                        self._kill(r)
                for r in self.names:
                    rb = self.robots.get(r)
                    if rb and rb["cgroup"]:
                        _cgroup(rb["cgroup"], self.mode).remove()
                if self.tb:
                    net.remove(self.tb, self.names)
                for p in list(self._popen.values()):
                    try:
                        p.wait(2)
                    except subprocess.TimeoutExpired:
                        pass
                self._popen.clear()
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
                self._restore_handlers()

    def detach(self) -> None:
        """Leave the testbed running after this process exits (``ramps testbed up``)."""
        self._restore_handlers()
        if self._atexit:
            atexit.unregister(self.down)
            self._atexit = False
        self._popen.clear()  # not ours to reap any more

    def _install_handlers(self) -> None:
        if not self._atexit:
            atexit.register(self.down)
            self._atexit = True
        if threading.current_thread() is not threading.main_thread():
            return
        for sig in (signal.SIGINT, signal.SIGTERM):
            prev = signal.getsignal(sig)
            self._old_handlers[sig] = prev

            def handler(signum: int, frame: FrameType | None, prev: _Handler = prev) -> Any:
                self.down()
                if callable(prev):
                    return prev(signum, frame)
                if signum == signal.SIGINT:
                    raise KeyboardInterrupt
                raise SystemExit(128 + signum)

            signal.signal(sig, handler)

    def _restore_handlers(self) -> None:
        if self._old_handlers and threading.current_thread() is threading.main_thread():
            for sig, prev in self._old_handlers.items():
                try:
                    signal.signal(sig, prev if prev is not None else signal.SIG_DFL)
                except (ValueError, TypeError):
                    pass
            self._old_handlers = {}
        if self._atexit and self._down:
            atexit.unregister(self.down)
            self._atexit = False

    def __enter__(self) -> "Testbed":
        return self.up()

    def __exit__(self, *exc: object) -> None:
        self.down()


def watch_team(testbed: "Testbed", *, redial: bool = False) -> "TeamWatcher":
    """A plain Zenoh session in the root namespace that watches the team:
    liveliness and the latest load report of each robot
    (``ramps.runtime.watch.TeamWatcher``).

    ``redial``: an endpoint that does not answer yet is dialled again every
    0.1-0.5 s, not Zenoh's 1 s backing off to 4 s: for a watcher opened
    while the nodes still start (``Testbed.wait_alive``), which with the
    default saw robots up to 4 s after they had joined.

    Used instead of a ``Team`` client for readiness and status because it
    is closed by its ``with`` block whatever interrupts it (a Ctrl-C in the
    middle of ``Team()`` would leave a session whose thread blocks exit)."""
    from ramps.runtime.watch import TeamWatcher

    config = testbed.zenoh_config()
    if redial:
        config.insert_json5("connect/retry", "{period_init_ms: 100, period_max_ms: 500, period_increase_factor: 2}")
    return TeamWatcher.open(config, testbed.team)
