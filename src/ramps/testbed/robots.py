"""A testbed's robots as processes, and what every robot's node is told.

How this works: ``RobotProcesses`` is the part of ``Testbed`` that starts
processes inside a robot, finds them, signals and reaps them; it is given
the testbed's robot records (``RobotRecord``, shared: it writes no pid into
them itself), the cgroup mode, the Python to run and the table of processes
this process started. ``ramps.testbed.bed`` builds the network and cgroups
and takes everything down; ``ramps.testbed.faults`` breaks robots.

* A process enters its robot's cgroup with ``RobotCgroup.wrap`` (a shell
  joins the cgroup, then execs) and the namespace with ``nsenter --net``
  rather than ``ip netns exec``: the latter remounts ``/sys`` in a new
  mount namespace, which would hide ``/sys/fs/cgroup`` from the node. It
  runs in its own session with a clean environment and no Zenoh shared
  memory, and is recorded as (pid, start time).
* A robot's processes are the members of its cgroup and its recorded pids;
  ``kill`` repeats SIGKILL until the cgroup is empty (a worker may be
  forking).
* Background load is busy processes in the same namespace and cgroup (the
  paper's ``stress``); the per-program CPU caps are one process for the
  whole testbed (``ramps.testbed.caps``), in the root namespace.
* Each robot's node is ``python -m ramps.cli node`` (``Testbed._node_cmd``);
  ``node_config_file`` writes the testbed's node settings, and a robot's
  own over them, as the node's config file; ``check_config`` refuses an
  unknown setting before any node starts.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from ramps.testbed import net
from ramps.testbed.procs import (RobotRecord, TestbedError, _alive, _cgroup, _cgroup_pids, _clean_env, _proc_stat,
                                 _signal_all)

STATE_DIR = Path(os.environ.get("RAMPS_TESTBED_STATE", "/run/ramps"))
PORT = 7447


class RobotProcesses:
    """The processes of a testbed's robots: started inside a robot, found, signalled, reaped."""

    def __init__(self, robots: dict[str, RobotRecord], mode: str, python: str,
                 popen: dict[int, subprocess.Popen[bytes]]) -> None:
        #: the testbed's robots, by name (the testbed's own dict: filled when it comes up)
        self.robots = robots
        self.mode = mode
        self.python = python
        #: what this process started, by pid, to reap
        self.popen = popen

    def record(self, robot: str) -> RobotRecord:
        """The robot's record; TestbedError for a robot this testbed does not have."""
        if robot not in self.robots:
            raise TestbedError(f"unknown robot {robot!r}; this testbed has {', '.join(self.robots) or 'none up'}")
        return self.robots[robot]

    def spawn(self, robot: str, argv: list[str], log: Path | None) -> tuple[int, int | None]:
        """Start ``argv`` inside the robot's namespace and cgroup; its (pid, start time)."""
        rb = self.robots[robot]
        cg = _cgroup(rb["cgroup"], self.mode)
        full = cg.wrap(["nsenter", f"--net={net.NETNS_DIR / rb['ns']}", *argv])
        # no Zenoh shared memory between robots that share this host: it carried their
        # large messages around the emulated network (NodeSettings.shared_memory)
        env = dict(_clean_env(), RAMPS_ROBOT=robot, RAMPS_SHARED_MEMORY="0")
        pid, start = self._popen(full, log, env)
        deadline = time.monotonic() + 2.0  # joined the cgroup (the shell's first step) before we return
        p = self.popen[pid]
        while pid not in _cgroup_pids(rb["cgroup"][:1]) and p.poll() is None and time.monotonic() < deadline:
            time.sleep(0.002)
        return pid, start

    def spawn_root(self, argv: list[str], log: Path | None) -> list[int | None]:
        """Start ``argv`` in the root namespace (the caps process); [pid, start time]."""
        return list(self._popen(argv, log, _clean_env()))

    def _popen(self, argv: list[str], log: Path | None, env: dict[str, str]) -> tuple[int, int | None]:
        out = open(log, "ab") if log else None
        try:
            p = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL if out is None else out,
                                 stderr=subprocess.STDOUT, env=env, start_new_session=True, close_fds=True)
        finally:
            if out is not None:
                out.close()
        self.popen[p.pid] = p
        st = _proc_stat(p.pid)
        return p.pid, st[1] if st else None

    def stop(self, pid: int | None, start: int | None) -> None:
        """SIGKILL one recorded process (the caps process) and reap it."""
        if pid and _alive(pid, start) != "dead":
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            p = self.popen.pop(pid, None)
            if p is not None:
                p.wait(2)

    def start_load(self, robot: str, n: int) -> None:
        """``n`` busy processes in the robot (the paper's ``stress``), recorded in its ``load_pids``."""
        rb = self.robots[robot]
        for _ in range(n):
            rb["load_pids"].append(self.spawn(robot, [self.python, "-c", "while True: pass"], None))

    def state(self, robot: str) -> str:
        """'running', 'stopped' or 'dead' of the robot's node."""
        rb = self.record(robot)
        pid = rb["pid"]
        if pid is None:
            return "dead"
        p = self.popen.get(pid)
        if p is not None and p.poll() is not None:
            return "dead"
        return _alive(pid, rb["start"])

    def pids(self, robot: str) -> list[int]:
        """Every live process of the robot: its cgroup's members and its recorded pids."""
        rb = self.robots[robot]
        pids = set(_cgroup_pids(rb["cgroup"]))
        for pid, start in [(rb["pid"], rb["start"]), *rb["load_pids"]]:
            if pid is not None and _alive(pid, start) != "dead":
                pids.add(pid)
        return sorted(pids)

    def kill(self, robot: str) -> None:
        """SIGKILL every process of the robot, until its cgroup is empty."""
        rb = self.robots[robot]
        if rb["pid"] and _alive(rb["pid"], rb["start"]) != "dead":
            try:
                os.killpg(rb["pid"], signal.SIGKILL)
            except (ProcessLookupError, PermissionError):
                pass
        for _ in range(50):  # a worker may be forking: repeat until the cgroup is empty
            pids = self.pids(robot)
            if not pids:
                break
            _signal_all(pids, signal.SIGKILL)
            _signal_all(pids, signal.SIGCONT)  # a stopped process dies only once continued on some kernels
            time.sleep(0.02)
        self.reap()

    def status(self, robot: str, have_ns: set[str]) -> dict[str, Any]:
        """The robot as ``Testbed.status`` shows it (``have_ns``: the host's network namespaces)."""
        rb = self.robots[robot]
        ns_ok = rb["ns"] in have_ns
        loads = sum(1 for p, s in rb["load_pids"] if _alive(p, s) != "dead")
        return dict(robot=robot, ip=rb["ip"], namespace=rb["ns"] if ns_ok else None,
                    link=net.link_state(rb["ns"]) if ns_ok else "missing", process=self.state(robot),
                    pid=rb["pid"], load=rb["load"], load_running=loads, faults=list(rb["faults"]))

    def wait_all(self) -> None:
        """Wait up to 2 s for each process this one started (all killed), and forget them."""
        for p in list(self.popen.values()):
            try:
                p.wait(2)
            except subprocess.TimeoutExpired:
                pass
        self.popen.clear()

    def reap(self) -> None:
        """Wait for the processes this one started that have exited."""
        for pid, p in list(self.popen.items()):
            if p.poll() is not None:
                del self.popen[pid]


def check_robots(robots: int | list[str], discovery: str, loaded: Mapping[str, int],
                 robot_config: Mapping[str, object]) -> list[str]:
    """A testbed's robot names (``robots``: how many, or the names); ValueError for no robot,
    an unknown discovery, or a robot that ``loaded`` or ``robot_config`` names but the testbed lacks."""
    names = [f"r{i}" for i in range(1, robots + 1)] if isinstance(robots, int) else list(robots)
    if not names:
        raise ValueError("a testbed needs at least one robot")
    if discovery not in ("both", "multicast", "connect"):
        raise ValueError("discovery must be both, multicast or connect")
    net.check_names("t250", names)
    for r in loaded:
        if r not in names:
            raise ValueError(f"loaded robot {r!r} is not one of {', '.join(names)}")
    for r in robot_config:
        if r not in names:
            raise ValueError(f"robot_config names {r!r}, not one of {', '.join(names)}")
    return names


def node_config_file(log_dir: Path, robot: str, config: Mapping[str, Any],
                     robot_config: Mapping[str, Mapping[str, Any]]) -> Path:
    """``config`` as a node's config file in ``log_dir``; a robot with settings of
    its own (``robot_config``) gets its own file, those settings over ``config``."""
    own = robot_config.get(robot, {})
    path = log_dir / (f"node-config-{robot}.toml" if own else "node-config.toml")
    if not path.exists():
        merged = {**config, **own, "core": {**config.get("core", {}), **own.get("core", {})}}
        top = [f"{k} = {json.dumps(v)}" for k, v in sorted(merged.items()) if k != "core"]
        core = [f"{k} = {json.dumps(v)}" for k, v in sorted(merged["core"].items())]
        path.write_text("\n".join(top + (["[core]"] + core if core else [])) + "\n")
    return path


def check_config(config: Mapping[str, Any]) -> dict[str, Any]:
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
