"""A team of real ``ramps node`` processes on this one machine.

How this works: each robot is a ``python -m ramps.cli node`` process with
its own loopback endpoint on a free port, multicast off, connected to the
first robot (gossip builds the mesh). With ``cpu_quota`` and root, each
robot also gets its own cpu cgroup (v1 or v2) whose quota makes it a small
computer of that many host cores, so five robots really are five slow
machines on a 2-core host; the node then measures its load within its
cgroup. ``add_load`` starts busy processes inside one robot (the paper's
``stress``). Everything started is stopped, and every cgroup removed, on
``close()``, also when the caller fails.

Used by ``ramps demo`` and ``ramps bench dispatch``; tests may use it too.
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path

from ramps.errors import NoTeam
from ramps.runtime.measure import cgroup_tree

CG_ROOT = Path("/sys/fs/cgroup")


def partial_views(sees: dict[str, int | None], size: int) -> dict[str, int | None]:
    """Of a team of ``size`` running robots, those whose own load reports say
    they do not see all ``size - 1`` others yet (None: no count reported),
    with what they see. Teams are handed over only when this is empty."""
    return {robot: n for robot, n in sees.items() if (n or 0) < size - 1}


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def cgroup_mode() -> str | None:
    """'v2', 'v1' or None when this process cannot make cpu cgroups."""
    if os.geteuid() != 0:
        return None
    if (CG_ROOT / "cgroup.controllers").exists():
        if "cpu" in (CG_ROOT / "cgroup.controllers").read_text().split() and os.access(CG_ROOT, os.W_OK):
            return "v2"
        return None
    if (CG_ROOT / "cpu" / "cpu.cfs_quota_us").exists() and os.access(CG_ROOT / "cpu", os.W_OK):
        return "v1"
    return None


class RobotCgroup:
    """One robot's cpu cgroup (and cpuacct on v1, for its CPU usage)."""

    def __init__(self, name: str, quota: float, mode: str) -> None:
        self.mode = mode
        period = 100_000
        if mode == "v2":
            self.dirs = [CG_ROOT / name]
            self.dirs[0].mkdir()
            (self.dirs[0] / "cpu.max").write_text(f"{int(quota * period)} {period}")
        else:
            self.dirs = [CG_ROOT / "cpu" / name]
            self.dirs[0].mkdir()
            (self.dirs[0] / "cpu.cfs_period_us").write_text(str(period))
            (self.dirs[0] / "cpu.cfs_quota_us").write_text(str(int(quota * period)))
            acct = CG_ROOT / "cpuacct" / name
            if (CG_ROOT / "cpuacct" / "cpuacct.usage").exists():
                acct.mkdir()
                self.dirs.append(acct)

    def enter(self) -> None:
        """Move the calling process in (used between fork and exec)."""
        for d in self.dirs:
            (d / "cgroup.procs").write_text(str(os.getpid()))

    def wrap(self, argv: list[str]) -> list[str]:
        """``argv`` run inside this cgroup from its first instruction, with no
        preexec hook: a shell joins the cgroup, then execs ``argv``."""
        joins = " && ".join(f"echo $$ > {d / 'cgroup.procs'}" for d in self.dirs)
        return ["/bin/sh", "-c", f'{joins} && exec "$@"', "sh", *argv]

    def remove(self) -> None:
        """Remove the cgroup, and first any child cgroups (the testbed's
        per-program caps), moving what is left in them to the root."""
        for d in self.dirs:
            for c in cgroup_tree(d):  # children first; ``d`` itself last
                _remove_one(c, d.parent)


def _remove_one(d: Path, root: Path) -> None:
    """rmdir one cgroup once its processes are moved to ``root``."""
    for _ in range(50):
        try:
            for pid in (d / "cgroup.procs").read_text().split():
                try:
                    (root / "cgroup.procs").write_text(pid)
                except OSError:
                    pass
            d.rmdir()
            break
        except FileNotFoundError:
            break
        except OSError:
            time.sleep(0.05)


class LocalTeam:
    def __init__(self, robots: int | list[str] = 3, *, team: str | None = None, cores: int | None = None,
                 speed: float | None = None, cpu_quota: float | None = None, policy: str | None = None,
                 programs: list[str] | None = None, env: dict[str, str] | None = None,
                 log_dir: str | None = None, lease_ms: int | None = None, keep_logs: bool = False) -> None:
        self.names = [f"r{i}" for i in range(1, robots + 1)] if isinstance(robots, int) else list(robots)
        self.team = team or f"local-{uuid.uuid4().hex[:8]}"
        self.cores = cores
        self.speed = speed
        self.cpu_quota = cpu_quota
        self.policy = policy
        self.programs = list(programs or [])
        self.env = dict(os.environ if env is None else env)
        self.lease_ms = lease_ms
        self.log_dir = Path(log_dir or tempfile.mkdtemp(prefix="ramps-team-"))
        # a log dir we made ourselves goes with a clean close; kept when asked, or when the team ends in an error
        self._own_logs = log_dir is None and not keep_logs
        self.mode = cgroup_mode() if cpu_quota is not None else None
        if cpu_quota is not None and self.mode is None:
            raise PermissionError("emulated robots need root and writable cpu cgroups (v1 or v2)")
        self.ports: dict[str, int] = {}
        self.procs: dict[str, subprocess.Popen] = {}
        self.loads: dict[str, list[subprocess.Popen]] = {}
        self.cgroups: dict[str, RobotCgroup] = {}
        self._seed: str | None = None

    # ------------------------------------------------------------ nodes
    def endpoint(self, name: str) -> str:
        return f"tcp/127.0.0.1:{self.ports[name]}"

    @property
    def seed(self) -> str:
        return self._seed or self.endpoint(self.names[0])

    def start(self, timeout: float = 30.0) -> "LocalTeam":
        try:
            for name in self.names:
                self.start_node(name, wait=False)
            self.wait_alive(self.names, timeout)
        except BaseException:
            self._own_logs = False  # the error names the log dir: keep it
            self.close()
            raise
        return self

    def start_node(self, name: str, *, wait: bool = True, cores: int | None = None, policy: str | None = None,
                   timeout: float = 30.0) -> None:
        if name not in self.names:
            self.names.append(name)
        self.ports[name] = free_port()
        if self._seed is None:
            self._seed = self.endpoint(name)
        cmd = [sys.executable, "-m", "ramps.cli", "node", "--robot", name, "--team", self.team,
               "--listen", self.endpoint(name), "--connect", self.seed, "--no-multicast"]
        for flag, value in (("--cores", cores or self.cores), ("--speed", self.speed),
                            ("--policy", policy or self.policy), ("--lease-ms", self.lease_ms)):
            if value is not None:
                cmd += [flag, str(value)]
        for p in self.programs:
            cmd += ["--program", p]
        pre = None
        if self.mode is not None:
            cg = self.cgroups.get(name) or RobotCgroup(f"ramps-{self.team}-{name}", self.cpu_quota, self.mode)
            self.cgroups[name] = cg
            pre = cg.enter
        env = dict(self.env, RAMPS_ROBOT=name)
        log = open(self.log_dir / f"{name}.log", "ab")
        self.procs[name] = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=env, preexec_fn=pre,
                                            start_new_session=True)
        log.close()
        if wait:
            self.wait_alive([name], timeout)

    def wait_alive(self, names: list[str], timeout: float = 30.0) -> None:
        from ramps.runtime.client import Team

        s = self._client_settings()
        deadline = time.monotonic() + timeout
        t = None
        try:
            while True:
                dead = [n for n in names if self.procs[n].poll() is not None]
                if dead:
                    raise NoTeam(f"node(s) {', '.join(dead)} exited at start; see {self.log_dir}")
                try:
                    t = t or Team(s, robot=names[0], timeout=0.5)  # short: notice dead nodes
                except NoTeam:
                    t = None
                blind: dict[str, int | None] = {}
                if t is not None:
                    rows = {r.robot: r for r in t.status().robots}
                    running = [n for n, p in self.procs.items() if p.poll() is None]
                    if all(n in rows and rows[n].alive for n in names):
                        # and each node sees every other one, so the first
                        # programs are not placed on part of the team
                        blind = partial_views({n: rows[n].sees for n in running if n in rows}, len(running))
                        if not blind:
                            return
                if time.monotonic() > deadline:
                    seeing = f" (nodes that do not see all their teammates yet: {blind})" if blind else ""
                    raise NoTeam(f"nodes {names} did not all join team {self.team} within {timeout:g} s"
                                 f"{seeing}; see {self.log_dir}")
                time.sleep(0.05)
        finally:
            if t is not None:
                t.close()

    def stop_node(self, name: str, sig: int = signal.SIGTERM, timeout: float = 15.0) -> int | None:
        proc = self.procs.get(name)
        if proc is None or proc.poll() is not None:
            return proc.returncode if proc else None
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            pass
        try:
            return proc.wait(timeout)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            return proc.wait(5)

    def kill_node(self, name: str) -> None:
        """A crash: SIGKILL the robot's node and its workers."""
        self.stop_node(name, signal.SIGKILL)

    def add_load(self, name: str, processes: int = 8) -> None:
        """Busy processes inside robot ``name`` (the paper's ``stress``)."""
        cg = self.cgroups.get(name)
        for _ in range(processes):
            self.loads.setdefault(name, []).append(subprocess.Popen(
                [sys.executable, "-c", "while True: pass"], preexec_fn=cg.enter if cg else None,
                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True))

    def _client_settings(self):
        """A client of this team: connects to the seed robot, listens nowhere."""
        from ramps.runtime.settings import load_settings

        return load_settings(flags={"team": self.team, "connect": [self.seed], "multicast": False, "listen": []},
                             default_robot=False, environ={})

    def client(self, robot: str | None = None, timeout: float = 10.0):
        from ramps.runtime.client import Team

        return Team(self._client_settings(), robot=robot or self.names[0], timeout=timeout)

    # ------------------------------------------------------------ cleanup
    def close(self) -> None:
        for procs in self.loads.values():
            for p in procs:
                if p.poll() is None:
                    p.kill()
                p.wait()
        self.loads.clear()
        for name in list(self.procs):
            self.stop_node(name, signal.SIGTERM, timeout=10)
        for cg in self.cgroups.values():
            cg.remove()
        self.cgroups.clear()
        if self._own_logs:
            shutil.rmtree(self.log_dir, ignore_errors=True)

    def __enter__(self) -> "LocalTeam":
        return self.start()

    def __exit__(self, *exc) -> None:
        if exc[0] is not None:
            self._own_logs = False  # the nodes' logs are what explains the error
        self.close()
