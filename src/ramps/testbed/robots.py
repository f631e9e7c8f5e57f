"""A testbed's robots as processes, and the state file that records them.

How this works: ``Robots`` is the part of ``Testbed`` that starts
processes inside a robot (``ramps.testbed.bed`` builds the network and
cgroups and takes everything down; ``ramps.testbed.faults`` breaks robots).

* Each robot's node is ``python -m ramps.cli node`` listening on
  ``tcp/<robot ip>:7447``; unless ``discovery="multicast"`` every robot but
  the first dials the first one (the seed), and unless
  ``discovery="connect"`` they also scout by multicast inside the bridge.
  Every node gets the same options (cores, speed, policy, lease, programs,
  the testbed's config as a config file), a decision trace in the log
  directory and a durable record under ``records-<tb>`` in the state
  directory.
* A process enters its robot's cgroup with ``RobotCgroup.wrap`` (a shell
  joins the cgroup, then execs) and the namespace with ``nsenter --net``
  rather than ``ip netns exec``: the latter remounts ``/sys`` in a new
  mount namespace, which would hide ``/sys/fs/cgroup`` from the node. It
  runs in its own session with a clean environment and no Zenoh shared
  memory, and is recorded as (pid, start time).
* Background load is busy processes in the same namespace and cgroup (the
  paper's ``stress``); the per-program CPU caps are one process for the
  whole testbed (``ramps.testbed.caps``), in the root namespace.
* The state file ``<state dir>/testbed-<tb>.json`` holds the testbed's
  settings and every ``RobotRecord``; it is written whole to a temporary
  file and renamed, so a reader never sees half of it.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ramps.testbed import net
from ramps.testbed.procs import RobotRecord, _alive, _cgroup, _cgroup_pids, _clean_env, _proc_stat

STATE_DIR = Path(os.environ.get("RAMPS_TESTBED_STATE", "/run/ramps"))
PORT = 7447


class Robots:
    """The process and state-file methods of ``Testbed`` (a mixin: ``self`` is a Testbed)."""

    if TYPE_CHECKING:  # what the mixin uses of ``Testbed`` (ramps.testbed.bed)
        tb: str | None
        x: int
        names: list[str]
        robots: dict[str, RobotRecord]
        mode: str
        quota: float
        cores: int | None
        speed: float | None
        policy: str | None
        lease_ms: int | None
        programs: list[str]
        config: dict[str, Any]
        robot_config: dict[str, dict[str, Any]]
        discovery: str
        python: str
        state_dir: Path
        loaded: dict[str, int]
        caps: bool
        caps_pid: list[int | None]
        log_dir: Path | None
        _popen: dict[int, subprocess.Popen[bytes]]

        @property
        def team(self) -> str: ...

    # ------------------------------------------------------------ the state file
    @property
    def state_file(self) -> Path:
        """``<state dir>/testbed-<tb>.json``: what ``Testbed.attach`` reads."""
        return self.state_dir / f"testbed-{self.tb}.json"

    def _save(self) -> None:
        """Write the state file whole (a temporary file, renamed over it)."""
        st = dict(tb=self.tb, x=self.x, team=self.team, quota=self.quota, cores=self.cores, speed=self.speed,
                  policy=self.policy, lease_ms=self.lease_ms, programs=self.programs, discovery=self.discovery,
                  python=self.python, mode=self.mode, loaded=self.loaded, caps=self.caps, caps_pid=self.caps_pid, config=self.config,
                  robot_config=self.robot_config,
                  log_dir=str(self.log_dir) if self.log_dir else None, created_by=os.getpid(),
                  robots=[self.robots[r] for r in self.names if r in self.robots])
        tmp = self.state_file.with_suffix(".tmp")
        tmp.write_text(json.dumps(st, indent=1))
        tmp.replace(self.state_file)

    # ------------------------------------------------------------ a robot's processes
    def _node_cmd(self, robot: str) -> list[str]:
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
            cmd += ["--config", str(self._config_file(robot))]
        if self.log_dir:  # every decision, for experiments and post-mortems: <log_dir>/<robot>.trace.jsonl
            cmd += ["--trace", str(self.log_dir / f"{robot}.trace.jsonl")]
        cmd += ["--state-dir", str(self.records_dir)]  # each robot's durable record, removed with the testbed
        return cmd

    @property
    def records_dir(self) -> Path:
        """Where the robots' nodes keep their durable records (``ramps.runtime.store``)."""
        return self.state_dir / f"records-{self.tb}"

    def _config_file(self, robot: str) -> Path:
        """``config`` as every node's config file, in the log directory; a robot
        with settings of its own (``robot_config``) gets its own file."""
        assert self.log_dir is not None
        own = self.robot_config.get(robot, {})
        path = self.log_dir / (f"node-config-{robot}.toml" if own else "node-config.toml")
        if not path.exists():
            config = {**self.config, **own, "core": {**self.config.get("core", {}), **own.get("core", {})}}
            top = [f"{k} = {json.dumps(v)}" for k, v in sorted(config.items()) if k != "core"]
            core = [f"{k} = {json.dumps(v)}" for k, v in sorted(config["core"].items())]
            path.write_text("\n".join(top + (["[core]"] + core if core else [])) + "\n")
        return path

    def _spawn(self, robot: str, argv: list[str], log: Path | None) -> tuple[int, int | None]:
        rb = self.robots[robot]
        cg = _cgroup(rb["cgroup"], self.mode)
        full = cg.wrap(["nsenter", f"--net={net.NETNS_DIR / rb['ns']}", *argv])
        # no Zenoh shared memory between robots that share this host: it carried their
        # large messages around the emulated network (NodeSettings.shared_memory)
        env = dict(_clean_env(), RAMPS_ROBOT=robot, RAMPS_SHARED_MEMORY="0")
        out = open(log, "ab") if log else None
        try:
            p = subprocess.Popen(full, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL if out is None else out,
                                 stderr=subprocess.STDOUT, env=env, start_new_session=True, close_fds=True)
        finally:
            if out is not None:
                out.close()
        self._popen[p.pid] = p
        st = _proc_stat(p.pid)
        deadline = time.monotonic() + 2.0  # joined the cgroup (the shell's first step) before we return
        while p.pid not in _cgroup_pids(rb["cgroup"][:1]) and p.poll() is None and time.monotonic() < deadline:
            time.sleep(0.002)
        return p.pid, st[1] if st else None

    def _start_node(self, robot: str) -> None:
        rb = self.robots[robot]
        log = self.log_dir / f"{robot}.log" if self.log_dir else None
        rb["pid"], rb["start"] = self._spawn(robot, self._node_cmd(robot), log)

    def _start_caps(self) -> None:
        """The per-program CPU caps of every robot: one process for the testbed
        (ramps.testbed.caps), in the root namespace; it ends with the state file."""
        log = open(self.log_dir / "caps.log", "ab") if self.log_dir else None
        try:
            p = subprocess.Popen([self.python, "-m", "ramps.testbed.caps", str(self.state_file)],
                                 stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL if log is None else log,
                                 stderr=subprocess.STDOUT, env=_clean_env(), start_new_session=True, close_fds=True)
        finally:
            if log is not None:
                log.close()
        self._popen[p.pid] = p
        st = _proc_stat(p.pid)
        self.caps_pid = [p.pid, st[1] if st else None]
        self._save()

    def _stop_caps(self) -> None:
        pid, start = self.caps_pid
        if pid and _alive(pid, start) != "dead":
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            p = self._popen.pop(pid, None)
            if p is not None:
                p.wait(2)
        self.caps_pid = [None, None]

    def _start_load(self, robot: str, n: int) -> None:
        rb = self.robots[robot]
        for _ in range(n):
            rb["load_pids"].append(self._spawn_load(robot))

    def _spawn_load(self, robot: str) -> tuple[int, int | None]:
        """One busy process in ``robot`` (the paper's ``stress``)."""
        return self._spawn(robot, [self.python, "-c", "while True: pass"], None)

    def log_tail(self, robot: str, lines: int = 15) -> str:
        if self.log_dir is None:
            return "(no log)"
        try:
            return "\n".join((self.log_dir / f"{robot}.log").read_text(errors="replace").splitlines()[-lines:])
        except OSError:
            return "(no log)"


def _check_config(config: Mapping[str, Any]) -> dict[str, Any]:
    """Node settings for a testbed's robots: known names, scalar values (node settings: or lists
    of them, e.g. ``accelerators``); a typo is an error here, not a node that will not start."""
    from ramps.core.config import RampsConfig
    from ramps.runtime.settings import NodeSettings

    core = config.get("core", {})
    bad = sorted(set(config) - set(NodeSettings.__struct_fields__) - {"core"})
    bad += sorted(f"core.{k}" for k in set(core) - set(RampsConfig.__struct_fields__))
    if bad:
        raise ValueError(f"unknown node settings {', '.join(bad)} (see ramps.runtime.settings.NodeSettings "
                         "and ramps.core.config.RampsConfig)")
    scalar = (bool, int, float, str)
    settings = [(True, k, v) for k, v in config.items() if k != "core"] + [(False, k, v) for k, v in core.items()]
    for top, k, v in settings:
        listed = top and isinstance(v, list) and all(isinstance(x, scalar) for x in v)
        if not isinstance(v, scalar) and not listed:
            raise ValueError(f"node setting {k} must be a number, a string or a boolean (a node setting: or a "
                             f"list of them), got {v!r}")
    return {**{k: v for k, v in config.items() if k != "core"}, **({"core": dict(core)} if core else {})}
