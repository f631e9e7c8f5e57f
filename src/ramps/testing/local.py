"""``LocalTeam``: a team of real ``ramps node`` processes on this machine.

Loopback endpoints on free ports, multicast off, optionally one cpu cgroup
per robot; for end-to-end tests, the demo and the benchmarks. Every process
it starts is tagged in its environment, stopped on ``close()`` and checked
for: nothing of a closed team is left running.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import uuid
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import psutil

from ramps.runtime.accelerators import remove_slot_folders
from ramps.runtime.localteam import RobotCgroup, cgroup_mode, free_port, listening_ports, partial_views
from ramps.testing.procs import describe, killpg, tagged_processes

__all__ = ["LocalTeam", "NodeProc", "describe", "tagged_processes"]


class NodeProc:
    """One ``ramps node`` process of a ``LocalTeam``."""

    def __init__(self, name: str, proc: subprocess.Popen[bytes], port: int, log: Path, cores: int | None,
                 scheme: str = "tcp") -> None:
        self.name = name
        self.proc = proc
        self.port = port
        self.log = log
        self.cores = cores
        self.scheme = scheme

    @property
    def endpoint(self) -> str:
        return f"{self.scheme}/127.0.0.1:{self.port}"

    @property
    def pid(self) -> int:
        return self.proc.pid


class LocalTeam:
    """A team of real ``ramps node`` processes on this machine.

    Each robot is a ``python -m ramps.cli node`` process listening on its own
    loopback port, multicast off, connected to the first robot (gossip builds
    the mesh), in a team whose name is unique (``local-<hex>`` unless given).
    Used by ``ramps demo``, the benchmarks and the end-to-end tests::

        with LocalTeam(3, cores=2, speed=1.0) as t:      # r1, r2, r3, each seeing the others
            team = t.client("r1")                       # ramps.connect(...) to every node
            team.submit("echo", x=1).result(60)
            t.start_node("r4")                          # joins; waits until visible
            t.stop_node("r2")                           # SIGTERM to the node, waits for its exit
            t.kill_node("r3")                           # SIGKILL of its process group (a crash)

    ``robots`` is a count (r1..rN) or a list of names. ``cpu_quota`` (root
    and a writable cpu cgroup v1 or v2) puts every robot in its own cgroup of
    that many host cores, so five robots are five small computers on one
    host; ``add_load`` and ``spawn(..., robot=)`` start processes inside a
    robot's cgroup. ``secure=True`` gives the team its own CA in
    ``<log_dir>/team-ca``, every node its credentials (``credentials(name)``)
    and ``tls/`` endpoints; clients connect as the application ``app``.
    ``router=True`` starts a Zenoh router first (``ramps router``) and makes
    every node a Zenoh client of it (``--mode client``): a star of N links
    instead of a mesh of N(N-1)/2, as a large team runs; clients and probes
    connect to the router.

    Node output goes to ``<log_dir>/<robot>.log`` (``logs()`` for failure
    messages). A log dir the team made itself is removed on a clean close and
    kept when the team ends in an error or with ``keep_logs``. Every process
    started here carries ``RAMPS_LOCALTEAM=<team>`` in its environment;
    ``close()`` stops them all (SIGTERM to the nodes first when ``graceful``,
    so they flush their traces; SIGKILL of every process group otherwise),
    kills any tagged process that survived, removes the cgroups, and raises
    ``AssertionError`` naming the survivors if there were any.
    """

    TAG = "RAMPS_LOCALTEAM"

    def __init__(self, robots: int | list[str] = 3, log_dir: str | Path | None = None, *, team: str | None = None,
                 cores: int | None = None, speed: float | None = None, lease_ms: int | None = None,
                 policy: str | None = None, programs: Iterable[str] = (), cpu_quota: float | None = None,
                 env: Mapping[str, str] | None = None, keep_logs: bool = False, verbose: bool = False,
                 visible_timeout: float = 30.0, secure: bool = False, graceful: bool = True,
                 router: bool = False, trace: bool = False) -> None:
        self.names = [f"r{i}" for i in range(1, robots + 1)] if isinstance(robots, int) else list(robots)
        self.team = team or f"local-{uuid.uuid4().hex[:8]}"
        self.default_cores, self.speed, self.lease_ms, self.policy = cores, speed, lease_ms, policy
        self.programs, self.cpu_quota, self.verbose = tuple(programs), cpu_quota, verbose
        self.env = dict(os.environ if env is None else env)
        #: every node writes its decisions to ``<log_dir>/<robot>.trace.jsonl`` (``ramps node --trace``)
        self.trace = trace
        self.visible_timeout, self.graceful = visible_timeout, graceful
        self.mode = cgroup_mode() if cpu_quota is not None else None
        if cpu_quota is not None and self.mode is None:
            raise PermissionError("emulated robots need root and writable cpu cgroups (v1 or v2)")
        if router and secure:
            raise ValueError("LocalTeam: a router of a secured team needs its own credentials; not offered here")
        #: made at its first use when none is given (a team that never starts leaves none behind)
        self._log_dir = Path(log_dir) if log_dir is not None else None
        if self._log_dir is not None:
            self._log_dir.mkdir(parents=True, exist_ok=True)
        # a log dir made here goes with a clean close; kept when asked, or when the team ends in an
        # error (unless nothing was written in it)
        self._own_logs, self._made_log_dir = log_dir is None and not keep_logs, log_dir is None
        self.nodes: dict[str, NodeProc] = {}
        self.loads: dict[str, list[subprocess.Popen[bytes]]] = {}
        self.cgroups: dict[str, RobotCgroup] = {}
        self._procs: list[subprocess.Popen[Any]] = []
        self._clients: list[Any] = []
        self._seed: str | None = None
        self.secure, self.router = secure, router
        #: the router's endpoint and process, once started (``router``)
        self.router_endpoint: str | None = None
        self.router_proc: subprocess.Popen[bytes] | None = None
        self.scheme = "tls" if secure else "tcp"
        if secure:
            from ramps.runtime.security import create_ca

            create_ca(self.ca_dir, self.team)

    @property
    def log_dir(self) -> Path:
        """Where the nodes' logs, traces and records go: the folder given, or a
        temporary one made at the first use."""
        if self._log_dir is None:
            self._log_dir = Path(tempfile.mkdtemp(prefix="ramps-team-"))
        return self._log_dir

    ca_dir = property(lambda self: self.log_dir / "team-ca", doc="the team's certificate authority (``secure``)")
    tmp = property(lambda self: self.log_dir, doc="the directory of the logs (and processes' working directory)")

    @property
    def procs(self) -> dict[str, subprocess.Popen[bytes]]:
        return {n: node.proc for n, node in self.nodes.items()}

    @property
    def seed(self) -> str:
        """The endpoint every node connects to: the first robot started, or the router."""
        if self._seed is None:
            raise RuntimeError("no node started yet")
        return self._seed

    def endpoint(self, name: str) -> str:
        return self.nodes[name].endpoint

    def credentials(self, name: str) -> Path:
        """Robot (or application) ``name``'s credentials directory, issued on first use."""
        from ramps.runtime.security import BUNDLE_KEY, issue

        bundle = self.ca_dir / name
        return bundle if (bundle / BUNDLE_KEY).exists() else issue(self.ca_dir, name)

    def _secure_kwargs(self) -> dict[str, Any]:
        return {"secure": True, "credentials": self.credentials("app")} if self.secure else {}

    # ------------------------------------------------------------ lifecycle
    def start(self, timeout: float | None = None) -> LocalTeam:
        """Start every robot and wait until each is visible and sees all the others."""
        try:
            for name in self.names:
                self.start_node(name, wait=False)
            self.wait_visible(list(self.nodes), timeout)
        except BaseException:
            self._own_logs = False  # the error names the log dir: keep it
            self.close()
            raise
        return self

    def __enter__(self) -> LocalTeam:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        if exc[0] is not None:
            self._own_logs = False  # the nodes' logs are what explains the error
        self.close()

    def close(self) -> None:
        """Close clients, stop every process started here, remove the cgroups;
        fail if a process of this team survived."""
        for c in self._clients:
            try:
                c.close()
            except Exception:
                pass
        self._clients.clear()
        if self.graceful:
            for name, node in self.nodes.items():
                if node.proc.poll() is None:
                    self.stop_node(name, timeout=10, check=False)
        for p in self._procs:
            killpg(p)
        for p in self._procs:
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                pass
        deadline = time.monotonic() + 10
        left = self.leftovers()
        while left and time.monotonic() < deadline:
            for proc in left:
                try:
                    proc.kill()
                except psutil.Error:
                    pass
            time.sleep(0.1)
            left = self.leftovers()
        self.loads.clear()
        for cg in self.cgroups.values():
            cg.remove()
        self.cgroups.clear()
        remove_slot_folders(self.team)  # emulated accelerators' (their nodes may have been killed)
        if left:
            self._own_logs = False
            raise AssertionError(f"processes of team {self.team} survived: {describe(left)}")
        if self._log_dir is not None and (self._own_logs or (self._made_log_dir and not any(self._log_dir.iterdir()))):
            shutil.rmtree(self._log_dir, ignore_errors=True)

    def leftovers(self) -> list[psutil.Process]:
        """Live processes started by this team (tagged in their environment)."""
        return tagged_processes(self.TAG, self.team)

    # ------------------------------------------------------------ processes
    def _env(self, robot: str | None, extra: Mapping[str, str] | None = None) -> dict[str, str]:
        env = dict(self.env)
        env[self.TAG] = self.team
        env["PYTHONUNBUFFERED"] = "1"
        env["COLUMNS"] = "400"  # rich logs: one line per record, so tests can grep them
        if robot:
            env["RAMPS_ROBOT"] = robot
        # each robot's durable record in the team's own directory, not the user's
        env.setdefault("RAMPS_STATE_DIR", str(self.log_dir / "state"))
        # robots on one machine would all read its battery (a variable: a 0.1.0 node has no such flag)
        env.setdefault("RAMPS_BATTERY_SYSFS", "false")
        env.update(extra or {})
        return env

    def _popen(self, argv: list[str], *, log: Path, env: dict[str, str]) -> subprocess.Popen[bytes]:
        f = open(log, "ab")
        try:
            p = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=f, stderr=subprocess.STDOUT, env=env,
                                 cwd=self.log_dir, start_new_session=True)
        finally:
            f.close()
        self._procs.append(p)
        return p

    def _cgroup(self, name: str) -> RobotCgroup | None:
        if self.mode is None or self.cpu_quota is None:
            return None
        cg = self.cgroups.get(name)
        if cg is None:
            cg = self.cgroups[name] = RobotCgroup(f"ramps-{self.team}-{name}", self.cpu_quota, self.mode)
        return cg

    def node_argv(self, name: str, port: int, cores: int | None, policy: str | None) -> list[str]:
        """The command line of robot ``name``'s node."""
        where = ["--mode", "client"] if self.router else ["--listen", f"{self.scheme}/127.0.0.1:{port}"]
        argv = [sys.executable, "-m", "ramps.cli", "node", "--robot", name, "--team", self.team, *where,
                "--no-multicast"]
        for flag, value in (("--speed", self.speed), ("--lease-ms", self.lease_ms), ("--cores", cores),
                            ("--policy", policy or self.policy)):
            if value is not None:
                argv += [flag, f"{value:g}" if isinstance(value, float) else str(value)]
        if self.secure:
            argv += ["--secure", "--credentials", str(self.credentials(name))]
        if self._seed is not None:
            argv += ["--connect", self._seed]
        for prog in self.programs:
            argv += ["--program", prog]
        if self.verbose:
            argv.append("--verbose")
        if self.trace:
            argv += ["--trace", str(self.log_dir / f"{name}.trace.jsonl")]
        return argv

    def start_node(self, name: str, cores: int | None = None, extra_env: Mapping[str, str] | None = None, *,
                   wait: bool = True, extra_args: list[str] | None = None, policy: str | None = None,
                   timeout: float | None = None) -> NodeProc:
        """Start ``ramps node`` for robot ``name`` (again, after a stop or a
        crash); by default wait until it is visible."""
        if name in self.nodes and self.nodes[name].proc.poll() is None:
            raise ValueError(f"node {name} is already running")
        if name not in self.names:
            self.names.append(name)
        cores = self.default_cores if cores is None else cores
        if self.router and self._seed is None:
            self._start_router()
        port = free_port()
        argv = self.node_argv(name, port, cores, policy) + list(extra_args or [])
        cg = self._cgroup(name)
        if cg is not None:
            argv = cg.wrap(argv)
        log = self.log_dir / f"{name}.log"
        proc = self._popen(argv, log=log, env=self._env(name, extra_env))
        node = self.nodes[name] = NodeProc(name, proc, port, log, cores, self.scheme)
        if self._seed is None:
            self._seed = node.endpoint
        if wait:
            self.wait_visible([name], timeout)
        return node

    def _start_router(self) -> None:
        """The team's Zenoh router (``router``), listening before any node starts."""
        port = free_port()
        self.router_endpoint = self._seed = f"{self.scheme}/127.0.0.1:{port}"
        self.router_proc = proc = self._popen([sys.executable, "-m", "ramps.cli", "router", "--team", self.team,
                                               "--listen", self._seed, "--no-multicast"],
                                              log=self.log_dir / "router.log", env=self._env(None))
        self._wait_ports({port: proc}, time.monotonic() + 30)

    def spawn(self, argv: list[str], *, robot: str | None = None, name: str = "bg") -> subprocess.Popen[bytes]:
        """A background process of this team (stopped on close); inside ``robot``'s cgroup if it has one."""
        cg = self.cgroups.get(robot) if robot is not None else None
        if cg is not None:
            argv = cg.wrap(argv)
        return self._popen(argv, log=self.log_dir / f"{name}.log", env=self._env(None))

    def add_load(self, name: str, processes: int = 8) -> None:
        """Busy processes inside robot ``name`` (the paper's ``stress``)."""
        for _ in range(processes):
            self.loads.setdefault(name, []).append(
                self.spawn([sys.executable, "-c", "while True: pass"], robot=name, name=f"{name}-load"))

    def stop_node(self, name: str, sig: int = signal.SIGTERM, timeout: float = 30.0,
                  check: bool = True) -> int | None:
        """Signal the node (not its workers: a node hands its programs back)
        and wait for it to exit; returns its exit code. A node still running
        after ``timeout`` is an ``AssertionError`` (``check``) or is killed."""
        node = self.nodes[name]
        if node.proc.poll() is not None:
            return node.proc.returncode
        try:
            node.proc.send_signal(sig)
            return node.proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            if check:
                raise AssertionError(f"node {name} did not exit {timeout:g} s after signal {sig}\n{self.logs(name)}")
            killpg(node.proc)
            return node.proc.wait(timeout=5)

    def kill_node(self, name: str) -> None:
        """SIGKILL the node and its workers (a robot that crashes)."""
        node = self.nodes[name]
        killpg(node.proc)
        node.proc.wait(timeout=10)

    # ------------------------------------------------------------ looking
    def alive(self) -> list[str]:
        return [n for n, p in self.nodes.items() if p.proc.poll() is None]

    def endpoints(self, names: list[str] | None = None) -> list[str]:
        """Where a client reaches these nodes: their own endpoints, or the router."""
        if self.router_endpoint is not None:
            return [self.router_endpoint]
        return [self.nodes[n].endpoint for n in (names or self.alive())]

    def client(self, robot: str | None = None, *, timeout: float = 20.0, connect: list[str] | None = None,
               **options: Any) -> Any:
        """``ramps.connect`` to this team with ``robot`` (default: the first) as the origin; closed on
        close(). ``options``: more of ``ramps.connect``'s (``origin_grace``)."""
        import ramps

        team = ramps.connect(team=self.team, robot=robot or self.names[0], connect=connect or self.endpoints(),
                             multicast=False, timeout=timeout, **self._secure_kwargs(), **options)
        self._clients.append(team)
        return team

    def wait_visible(self, names: list[str], timeout: float | None = None) -> None:
        """Until every node in ``names`` holds its liveliness token and has published
        a load report that a fresh client (connected to every node) can see, and
        every running node reports that it sees all the others."""
        import ramps
        from ramps.errors import NoTeam

        timeout = self.visible_timeout if timeout is None else timeout
        deadline = time.monotonic() + timeout
        for n in names:
            if self.nodes[n].proc.poll() is not None:
                raise NoTeam(f"node {n} exited with {self.nodes[n].proc.returncode}; see {self.log_dir}\n"
                             + self.logs(n))
        self._wait_listening(names, deadline)
        probe = None
        try:
            while probe is None:
                try:
                    probe = ramps.connect(team=self.team, robot=names[0], connect=self.endpoints(),
                                          multicast=False, timeout=min(5.0, max(0.5, deadline - time.monotonic())),
                                          **self._secure_kwargs())
                except NoTeam:
                    if time.monotonic() > deadline:
                        raise NoTeam(f"node {names[0]} of team {self.team} never became visible; see "
                                     f"{self.log_dir}\n" + self.logs()) from None
            while True:
                st = {r.robot: r for r in probe.status().robots}
                missing = [n for n in names if n not in st or not st[n].alive or st[n].report_age is None]
                # and every running node sees every other one: a node that this
                # probe sees may not have reached its teammates yet (TLS, busy CI)
                running = self.alive()
                if not missing:
                    missing = list(partial_views({n: st[n].sees for n in running if n in st}, len(running)))
                if not missing:
                    return
                for n in missing:
                    if self.nodes[n].proc.poll() is not None:
                        raise NoTeam(f"node {n} exited with {self.nodes[n].proc.returncode}; see {self.log_dir}\n"
                                     + self.logs(n))
                if time.monotonic() > deadline:
                    sees = {n: st[n].sees for n in missing if n in st}
                    raise NoTeam(f"nodes {missing} of team {self.team} not visible, or not seeing all "
                                 f"{len(running) - 1} teammates (they see {sees}), after {timeout:g} s; see "
                                 f"{self.log_dir}\n" + self.logs())
                time.sleep(0.1)
        finally:
            if probe is not None:
                probe.close()

    wait_alive = wait_visible

    def _wait_listening(self, names: list[str], deadline: float) -> None:
        """Until every node in ``names`` listens on its port (or exited, or the
        deadline passed: the probe then tells why): a probe opened earlier
        would dial a closed port and wait out Zenoh's retry period."""
        if not self.router:  # clients of a router listen on none
            self._wait_ports({self.nodes[n].port: self.nodes[n].proc for n in names}, deadline)

    @staticmethod
    def _wait_ports(want: dict[int, subprocess.Popen[bytes]], deadline: float) -> None:
        """Until each process of ``want`` listens on its port, has exited, or ``deadline`` passed."""
        while want and time.monotonic() < deadline:
            bound = listening_ports()
            if bound is None:  # cannot tell: the caller waits as it would have
                return
            want = {p: proc for p, proc in want.items() if p not in bound and proc.poll() is None}
            if want:
                time.sleep(0.02)

    def worker_pids(self, name: str) -> list[int]:
        """The node's worker processes: forked by its fork server
        (``python -m ramps.runtime.worker --fork-server``), or its own children."""
        try:
            kids = psutil.Process(self.nodes[name].pid).children()
        except psutil.NoSuchProcess:
            return []
        out: list[int] = []
        for k in kids:
            try:
                cmd = k.cmdline()
                if "ramps.runtime.worker" not in " ".join(cmd):
                    continue
                if "--fork-server" in cmd:
                    out.extend(w.pid for w in k.children())
                else:
                    out.append(k.pid)
            except psutil.Error:
                continue
        return out

    def logs(self, name: str | None = None, tail: int = 4000) -> str:
        names = [name] if name else list(self.nodes)
        parts = []
        for n in names:
            try:
                text = self.nodes[n].log.read_text(errors="replace")
            except OSError:
                text = "(no log)"
            parts.append(f"----- {n} (pid {self.nodes[n].pid}, rc {self.nodes[n].proc.poll()}) -----\n"
                         f"{text[-tail:]}")
        return "\n".join(parts)

    def cli(self, *args: str, timeout: float = 60.0) -> subprocess.CompletedProcess[str]:
        """Run ``python -m ramps.cli ARGS`` in this team's environment (stopped at ``timeout``)."""
        p = subprocess.Popen([sys.executable, "-m", "ramps.cli", *args], stdin=subprocess.DEVNULL,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=self._env(None), cwd=self.log_dir,
                             start_new_session=True, text=True)
        self._procs.append(p)
        try:
            out, err = p.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            killpg(p)
            out, err = p.communicate()
            raise AssertionError(f"ramps {' '.join(args)} did not finish in {timeout:g} s\n{out}\n{err}") from None
        return subprocess.CompletedProcess(p.args, p.returncode, out, err)
