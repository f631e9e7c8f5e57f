"""A real ramps team on this machine, for end-to-end tests.

``LocalTeam`` starts ``ramps node`` processes (``python -m ramps.cli node``)
on loopback, each with its own robot name and Zenoh listen port, all in one
team whose name is unique to the test, with multicast off and every node
connecting to the first one (gossip builds the mesh). Nodes register the
programs of ``tests/e2eprogs.py`` and are started with ``RAMPS_ROBOT`` set,
so a result tells which robot ran it.

    with LocalTeam(3, tmp_path) as t:          # r1, r2, r3, all visible
        team = t.client("r1")                  # ramps.connect(...)
        team.submit("where", x=1).result(60)
        t.start_node("r4")                     # joins, waits until visible
        t.stop_node("r2")                      # SIGTERM, waits for the exit
        t.kill_node("r3")                      # SIGKILL of its process group

Everything the team starts (nodes, their workers, background load, CLI
runs) is tagged with ``RAMPS_E2E_RUN`` in its environment and killed on
exit, even when the test fails; ``leftover_processes()`` finds any that
survived. Node output goes to ``<tmp>/<robot>.log``; ``logs()`` returns it
for failure messages.

A secured team (``secure=True``): the team gets its own CA in
``<tmp>/team-ca``, every node its credentials (``credentials(name)``) and
``tls/`` endpoints, and ``client()`` / ``wait_visible`` connect with the
credentials of an application ``app``.

Optional cpu cgroups (``cgroups=True``, root and a writable cgroup v1 or v2
cpu controller needed, see ``cgroup_support()``): each node then runs in its
own cgroup with a CPU quota, so it measures its own load (``load_scope``
auto), as emulated robots sharing one host do; ``spawn(..., robot=...)``
starts background load inside a robot's cgroup.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path
from typing import Any

import psutil

from ramps.runtime.localteam import RobotCgroup, cgroup_mode, free_port, partial_views

TESTS_DIR = Path(__file__).resolve().parent
#: unique to this pytest process: every process a LocalTeam starts carries it
RUN_ID = f"{os.getpid()}-{uuid.uuid4().hex[:8]}"
RUN_ENV = "RAMPS_E2E_RUN"

PROGRAMS = ("where", "spin", "sleepy", "fail", "big")

#: every process group started by any LocalTeam of this run (for the final check)
_STARTED: list[subprocess.Popen] = []


def leftover_processes(run_id: str = RUN_ID) -> list[psutil.Process]:
    """Live processes started by this test run (tagged in their environment)."""
    found = []
    me = os.getpid()
    for p in psutil.process_iter(["pid"]):
        if p.pid == me:
            continue
        try:
            if p.status() == psutil.STATUS_ZOMBIE:
                continue
            if p.environ().get(RUN_ENV) == run_id:
                found.append(p)
        except (psutil.NoSuchProcess, psutil.AccessDenied, psutil.ZombieProcess, OSError):
            continue
    return found


def describe(procs: list[psutil.Process]) -> str:
    out = []
    for p in procs:
        try:
            out.append(f"{p.pid}: {' '.join(p.cmdline())}")
        except psutil.Error:
            out.append(f"{p.pid}: ?")
    return "; ".join(out)


def assert_no_leftovers(timeout: float = 10.0) -> None:
    """After a test module: no node, worker, load or CLI process this run
    started is alive (killed if so, and the check fails)."""
    deadline = time.monotonic() + timeout
    left = leftover_processes()
    while left and time.monotonic() < deadline:
        time.sleep(0.2)
        left = leftover_processes()
    for p in left:
        try:
            p.kill()
        except psutil.Error:
            pass
    assert not left, f"processes started by this test run survived it: {describe(left)}"
    assert all(p.poll() is not None for p in _STARTED)


# ---------------------------------------------------------------- cgroups
def cgroup_support() -> str | None:
    """None if this process may create cpu cgroups with a quota, else why not."""
    if os.geteuid() != 0:
        return "not root"
    mode = cgroup_mode()
    if mode is None:
        return "no writable cpu cgroup controller (v1 /sys/fs/cgroup/cpu or v2 with +cpu)"
    try:
        RobotCgroup(f"ramps-e2e-probe-{uuid.uuid4().hex[:8]}", 0.5, mode).remove()
    except OSError as exc:
        return f"cannot create a cpu cgroup: {exc}"
    return None


# ---------------------------------------------------------------- the team
class NodeProc:
    def __init__(self, name: str, proc: subprocess.Popen, port: int, log: Path, cores: int | None,
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
    def __init__(self, n: int, tmp: Path, *, cores: int | None = 2, lease_ms: int = 1000,
                 cgroups: bool = False, quota_cores: float = 1.0, programs=PROGRAMS,
                 verbose: bool = False, visible_timeout: float = 30.0, secure: bool = False) -> None:
        self.n = n
        self.tmp = Path(tmp)
        self.tmp.mkdir(parents=True, exist_ok=True)
        self.marks = self.tmp / "marks"
        self.marks.mkdir(exist_ok=True)
        self.team = f"e2e-{uuid.uuid4().hex[:12]}"
        self.default_cores = cores
        self.lease_ms = lease_ms
        self.use_cgroups = cgroups
        self.quota_cores = quota_cores
        self.programs = tuple(programs)
        self.visible_timeout = visible_timeout
        self.verbose = verbose
        self.nodes: dict[str, NodeProc] = {}
        self._procs: list[subprocess.Popen] = []
        self._clients: list[Any] = []
        self._cgroups: dict[str, RobotCgroup] = {}
        self._seed: str | None = None
        self.secure = secure
        self.scheme = "tls" if secure else "tcp"
        self.ca_dir = self.tmp / "team-ca"
        if secure:
            from ramps.runtime.security import create_ca

            create_ca(self.ca_dir, self.team)

    def credentials(self, name: str) -> Path:
        """Robot (or application) ``name``'s credentials directory, issued on first use."""
        from ramps.runtime.security import BUNDLE_KEY, issue

        bundle = self.ca_dir / name
        return bundle if (bundle / BUNDLE_KEY).exists() else issue(self.ca_dir, name)

    def _secure_kwargs(self) -> dict[str, Any]:
        return {"secure": True, "credentials": self.credentials("app")} if self.secure else {}

    # ------------------------------------------------------------ lifecycle
    def __enter__(self) -> LocalTeam:
        try:
            for i in range(1, self.n + 1):
                self.start_node(f"r{i}", wait=False)
            self.wait_visible(list(self.nodes))
        except BaseException:
            self.close()
            raise
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Close clients, kill every process started here, check none is left."""
        for c in self._clients:
            try:
                c.close()
            except Exception:
                pass
        self._clients.clear()
        for p in self._procs:
            self._killpg(p)
        for p in self._procs:
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                pass
        deadline = time.monotonic() + 10
        left = self.leftovers()
        while left and time.monotonic() < deadline:
            for p in left:
                try:
                    p.kill()
                except psutil.Error:
                    pass
            time.sleep(0.1)
            left = self.leftovers()
        for cg in self._cgroups.values():
            cg.remove()
        self._cgroups.clear()
        if left:
            raise AssertionError(f"processes of team {self.team} survived: {describe(left)}")

    def leftovers(self) -> list[psutil.Process]:
        return [p for p in leftover_processes() if self._tag_of(p) == self.team]

    @staticmethod
    def _tag_of(p: psutil.Process) -> str | None:
        try:
            return p.environ().get("RAMPS_E2E_TEAM")
        except psutil.Error:
            return None

    @staticmethod
    def _killpg(p: subprocess.Popen) -> None:
        try:
            os.killpg(p.pid, signal.SIGKILL)  # the node and its workers
        except (ProcessLookupError, PermissionError):
            pass

    # ------------------------------------------------------------ processes
    def _env(self, robot: str | None, extra: dict[str, str] | None = None) -> dict[str, str]:
        env = {k: v for k, v in os.environ.items() if not k.startswith("RAMPS_")}
        env["PYTHONPATH"] = os.pathsep.join([str(TESTS_DIR)] + [p for p in [os.environ.get("PYTHONPATH")] if p])
        env[RUN_ENV] = RUN_ID
        env["RAMPS_E2E_TEAM"] = self.team
        env["RAMPS_E2E_MARKS"] = str(self.marks)
        env["PYTHONUNBUFFERED"] = "1"
        env["COLUMNS"] = "400"  # rich logs: one line per record, so tests can grep them
        if robot:
            env["RAMPS_ROBOT"] = robot
        env.update(extra or {})
        return env

    def _popen(self, argv: list[str], *, log: Path, env: dict[str, str]) -> subprocess.Popen:
        f = open(log, "ab")
        try:
            p = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=f, stderr=subprocess.STDOUT, env=env,
                                 cwd=self.tmp, start_new_session=True)
        finally:
            f.close()
        self._procs.append(p)
        _STARTED.append(p)
        return p

    def start_node(self, name: str, cores: int | None = None, extra_env: dict[str, str] | None = None, *,
                   wait: bool = True, extra_args: list[str] | None = None) -> NodeProc:
        """Start ``ramps node`` for robot ``name``; by default wait until it is visible."""
        if name in self.nodes and self.nodes[name].proc.poll() is None:
            raise ValueError(f"node {name} is already running")
        cores = self.default_cores if cores is None else cores
        port = free_port()
        argv = [sys.executable, "-m", "ramps.cli", "node", "--robot", name, "--team", self.team,
                "--listen", f"{self.scheme}/127.0.0.1:{port}", "--no-multicast", "--speed", "1",
                "--lease-ms", str(self.lease_ms)]
        if self.secure:
            argv += ["--secure", "--credentials", str(self.credentials(name))]
        if cores is not None:
            argv += ["--cores", str(cores)]
        if self._seed is not None:
            argv += ["--connect", self._seed]
        for prog in self.programs:
            argv += ["--program", f"e2eprogs:{prog}"]
        if self.verbose:
            argv.append("--verbose")
        argv += extra_args or []
        if self.use_cgroups:
            cg = self._cgroups.get(name)
            if cg is None:
                cg = self._cgroups[name] = RobotCgroup(f"{self.team}-{name}", self.quota_cores, cgroup_mode())
            argv = cg.wrap(argv)
        log = self.tmp / f"{name}.log"
        proc = self._popen(argv, log=log, env=self._env(name, extra_env))
        node = self.nodes[name] = NodeProc(name, proc, port, log, cores, self.scheme)
        if self._seed is None:
            self._seed = node.endpoint
        if wait:
            self.wait_visible([name])
        return node

    def spawn(self, argv: list[str], *, robot: str | None = None, name: str = "bg") -> subprocess.Popen:
        """A background process of this test (killed at exit); inside ``robot``'s cgroup if given."""
        if robot is not None and self.use_cgroups:
            argv = self._cgroups[robot].wrap(argv)
        return self._popen(argv, log=self.tmp / f"{name}.log", env=self._env(None))

    def stop_node(self, name: str, sig: int = signal.SIGTERM, timeout: float = 30.0) -> int:
        """Signal the node and wait for it to exit; returns its exit code."""
        node = self.nodes[name]
        node.proc.send_signal(sig)
        try:
            return node.proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            raise AssertionError(f"node {name} did not exit {timeout:g} s after signal {sig}\n{self.logs(name)}")

    def kill_node(self, name: str) -> None:
        """SIGKILL the node and its workers (a robot that crashes)."""
        node = self.nodes[name]
        self._killpg(node.proc)
        node.proc.wait(timeout=10)

    # ------------------------------------------------------------ looking
    def alive(self) -> list[str]:
        return [n for n, p in self.nodes.items() if p.proc.poll() is None]

    def endpoints(self, names: list[str] | None = None) -> list[str]:
        return [self.nodes[n].endpoint for n in (names or self.alive())]

    def client(self, robot: str = "r1", *, timeout: float = 20.0, connect: list[str] | None = None):
        """``ramps.connect`` to this team with ``robot`` as the origin."""
        import ramps

        team = ramps.connect(team=self.team, robot=robot, connect=connect or self.endpoints(), multicast=False,
                             timeout=timeout, **self._secure_kwargs())
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
                raise AssertionError(f"node {n} exited with {self.nodes[n].proc.returncode}\n{self.logs(n)}")
        probe = None
        try:
            while probe is None:
                try:
                    probe = ramps.connect(team=self.team, robot=names[0], connect=self.endpoints(),
                                          multicast=False, timeout=min(5.0, max(0.5, deadline - time.monotonic())),
                                          **self._secure_kwargs())
                except NoTeam:
                    if time.monotonic() > deadline:
                        raise AssertionError(f"node {names[0]} of team {self.team} never became visible\n"
                                             + self.logs())
            while True:
                st = {r.robot: r for r in probe.status().robots}
                missing = [n for n in names if n not in st or not st[n].alive or st[n].report_age is None]
                # and every running node sees every other one: a node that this
                # probe sees may not have reached its teammates yet (TLS, busy CI)
                running = self.alive()
                others = len(running) - 1
                if not missing:
                    missing = list(partial_views({n: st[n].sees for n in running if n in st}, len(running)))
                if not missing:
                    return
                for n in missing:
                    if self.nodes[n].proc.poll() is not None:
                        raise AssertionError(f"node {n} exited with {self.nodes[n].proc.returncode}\n{self.logs(n)}")
                if time.monotonic() > deadline:
                    sees = {n: st[n].sees for n in missing if n in st}
                    raise AssertionError(f"nodes {missing} of team {self.team} not visible, or not seeing all "
                                         f"{others} teammates (they see {sees}), after {timeout:g} s\n"
                                         + self.logs())
                time.sleep(0.1)
        finally:
            if probe is not None:
                probe.close()

    def worker_pids(self, name: str) -> list[int]:
        """The node's worker processes: forked by its fork server
        (``python -m ramps.runtime.worker --fork-server``), or its own children."""
        try:
            kids = psutil.Process(self.nodes[name].pid).children()
        except psutil.NoSuchProcess:
            return []
        out = []
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

    def cli(self, *args: str, timeout: float = 60.0) -> subprocess.CompletedProcess:
        """Run ``python -m ramps.cli ARGS`` (tagged and killed at timeout)."""
        p = subprocess.Popen([sys.executable, "-m", "ramps.cli", *args], stdin=subprocess.DEVNULL,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=self._env(None), cwd=self.tmp,
                             start_new_session=True, text=True)
        self._procs.append(p)
        _STARTED.append(p)
        try:
            out, err = p.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            self._killpg(p)
            out, err = p.communicate()
            raise AssertionError(f"ramps {' '.join(args)} did not finish in {timeout:g} s\n{out}\n{err}")
        return subprocess.CompletedProcess(p.args, p.returncode, out, err)


def wait_for(pred, timeout: float, what: str, poll: float = 0.05):
    """Poll ``pred`` until it returns something true (returned), or fail
    saying ``what`` did not happen within ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while True:
        value = pred()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout:g} s waiting for {what}")
        time.sleep(poll)
