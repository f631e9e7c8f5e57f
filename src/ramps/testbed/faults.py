"""Fault injection on a testbed's robots: the paper's failures, and undoing them.

How this works: ``Faults`` is the part of ``Testbed`` that breaks robots
(``ramps.testbed.bed`` builds and removes them). Every fault is recorded in
the robot's ``faults`` list and the state file, so ``ramps testbed`` commands
from another process see it and ``recover`` undoes exactly what was done.

* ``crash``: SIGKILL to the node's process group and to every process in
  the robot's cgroup (node, workers, load), repeated until the cgroup is
  empty (a worker may be forking). ``recover`` starts a new node (and the
  same background load) in the same namespace and cgroup.
* ``cut``: ``ip link set eth0 down`` inside the namespace; processes run on.
* ``lossy``: drop each packet in and out with a probability (netem).
* ``freeze``: SIGSTOP to every process of the robot, until all are stopped;
  ``recover``: SIGCONT.
* ``add_load``/``remove_load``: busy processes inside the robot.
* ``restart``: not a fault: the node stopped (SIGTERM) and started again,
  as its supervisor does, with the same durable record.

Rules: a fault on a testbed that is not up, or on an unknown robot, raises
``TestbedError``; freezing a crashed robot too. Every method holds the
testbed's lock, so a fault and ``down()`` never interleave.
"""

from __future__ import annotations

import math
import os
import signal
import time
from typing import TYPE_CHECKING

from ramps.testbed import net
from ramps.testbed.procs import RobotRecord, TestbedError, _alive, _cgroup_pids, _proc_stat, _signal_all

if TYPE_CHECKING:
    import subprocess
    import threading


class Faults:
    """The fault-injection methods of ``Testbed`` (a mixin: ``self`` is a Testbed)."""

    if TYPE_CHECKING:  # what the mixin uses of ``Testbed`` (ramps.testbed.bed)
        robots: dict[str, RobotRecord]
        _popen: dict[int, subprocess.Popen[bytes]]
        _lock: threading.RLock
        _created: bool
        _down: bool

        def _robot(self, robot: str) -> RobotRecord: ...
        def _save(self) -> None: ...
        def _start_node(self, robot: str) -> None: ...
        def _start_load(self, robot: str, n: int) -> None: ...
        def wait_alive(self, robots: list[str] | None = None, timeout: float = 60.0) -> float: ...

    def process_state(self, robot: str) -> str:
        """'running', 'stopped' or 'dead' of the robot's node."""
        rb = self._robot(robot)
        pid = rb["pid"]
        if pid is None:
            return "dead"
        p = self._popen.get(pid)
        if p is not None and p.poll() is not None:
            return "dead"
        return _alive(pid, rb["start"])

    def _pids(self, robot: str) -> list[int]:
        """Every live process of the robot: its cgroup's members and its recorded pids."""
        rb = self.robots[robot]
        pids = set(_cgroup_pids(rb["cgroup"]))
        for pid, start in [(rb["pid"], rb["start"]), *rb["load_pids"]]:
            if pid is not None and _alive(pid, start) != "dead":
                pids.add(pid)
        return sorted(pids)

    def _kill(self, robot: str) -> None:
        rb = self.robots[robot]
        if rb["pid"] and _alive(rb["pid"], rb["start"]) != "dead":
            try:
                os.killpg(rb["pid"], signal.SIGKILL)
            except (ProcessLookupError, PermissionError):
                pass
        for _ in range(50):  # a worker may be forking: repeat until the cgroup is empty
            pids = self._pids(robot)
            if not pids:
                break
            _signal_all(pids, signal.SIGKILL)
            _signal_all(pids, signal.SIGCONT)  # a stopped process dies only once continued on some kernels
            time.sleep(0.02)
        self._reap()

    def _reap(self) -> None:
        for pid, p in list(self._popen.items()):
            if p.poll() is not None:
                del self._popen[pid]

    def restart(self, robot: str, *, timeout: float = 30.0) -> float:
        """Restart the robot's node as its supervisor does (``systemctl
        restart``): SIGTERM, wait for it to leave the team (SIGKILL after
        ``timeout``), start it again with the same command (the same durable
        record), and wait until it is alive and sees the team. Returns the
        seconds from the SIGTERM until it is back."""
        t0 = time.monotonic()
        with self._lock:
            self._live()
            rb = self._robot(robot)
            pid = rb["pid"]
            p = self._popen.get(pid) if pid is not None else None
            if pid and _alive(pid, rb["start"]) != "dead":
                os.kill(pid, signal.SIGTERM)
                deadline = time.monotonic() + timeout
                while _alive(pid, rb["start"]) != "dead" and (p is None or p.poll() is None):
                    if time.monotonic() > deadline:  # what a supervisor does next
                        os.killpg(pid, signal.SIGKILL)
                        deadline = math.inf
                    time.sleep(0.05)
            self._reap()
            self._start_node(robot)
            self._save()
        self.wait_alive([robot], timeout)
        return time.monotonic() - t0

    def crash(self, robot: str) -> None:
        """SIGKILL the robot's node, workers and load (a power cut)."""
        with self._lock:
            self._live()
            rb = self._robot(robot)
            self._kill(robot)
            rb["faults"] = [f for f in rb["faults"] if f != "frozen"] + ["crashed"] * ("crashed" not in rb["faults"])
            rb["load_pids"] = []
            self._save()

    def cut(self, robot: str) -> None:
        """Take the robot's network link down; its processes keep running."""
        with self._lock:
            self._live()
            rb = self._robot(robot)
            net.link_down(rb["ns"])
            if "cut" not in rb["faults"]:
                rb["faults"].append("cut")
            self._save()

    def lossy(self, robot: str, loss: float) -> None:
        """Drop each of the robot's packets, in and out, with probability
        ``loss`` (a poor WiFi link; TCP retransmits, so keep-alives arrive
        late rather than never). ``loss=0`` or ``recover`` ends it."""
        with self._lock:
            self._live()
            rb = self._robot(robot)
            net.set_loss(rb["ns"], loss)
            rb["faults"] = [f for f in rb["faults"] if f != "lossy"] + ["lossy"] * (loss > 0)
            self._save()

    def freeze(self, robot: str) -> None:
        """SIGSTOP every process of the robot (sockets stay open, nothing answers)."""
        with self._lock:
            self._live()
            rb = self._robot(robot)
            if "crashed" in rb["faults"]:
                raise TestbedError(f"robot {robot} is crashed; recover it before freezing it")
            if rb["pid"]:
                try:
                    os.killpg(rb["pid"], signal.SIGSTOP)
                except ProcessLookupError:
                    pass
            deadline = time.monotonic() + 2.0
            while True:  # until every process is stopped (signals are delivered asynchronously)
                running = [p for p in self._pids(robot) if (_proc_stat(p) or ("T", 0))[0] not in ("T", "t")]
                if not running or time.monotonic() > deadline:
                    break
                _signal_all(running, signal.SIGSTOP)
                time.sleep(0.005)
            if "frozen" not in rb["faults"]:
                rb["faults"].append("frozen")
            self._save()

    def recover(self, robot: str, *, wait: bool = True, timeout: float = 30.0) -> list[str]:
        """Undo every fault of the robot (link up, SIGCONT, restart a crashed
        node and its load); with ``wait``, until the root namespace sees it alive
        again. Returns the faults undone."""
        with self._lock:
            self._live()
            rb = self._robot(robot)
            undone = list(rb["faults"])
            if "cut" in undone or net.link_state(rb["ns"]) != "up":
                net.link_up(rb["ns"])
            if "lossy" in undone:
                net.set_loss(rb["ns"], 0)
            if "frozen" in undone:
                _signal_all(self._pids(robot), signal.SIGCONT)
                if rb["pid"]:
                    try:
                        os.killpg(rb["pid"], signal.SIGCONT)
                    except ProcessLookupError:
                        pass
            if "crashed" in undone or self.process_state(robot) == "dead":
                self._kill(robot)  # leftovers of the old incarnation, if any
                rb["load_pids"] = []
                self._start_node(robot)
                self._start_load(robot, rb["load"])
            rb["faults"] = []
            self._save()
        if wait:
            self.wait_alive([robot], timeout)
        return undone

    def add_load(self, robot: str, n: int = 1) -> None:
        """Start ``n`` busy processes inside the robot (its namespace and cgroup)."""
        if n < 0:
            raise ValueError("n must be >= 0")
        with self._lock:
            self._live()
            rb = self._robot(robot)
            rb["load"] += n
            if "crashed" not in rb["faults"]:
                self._start_load(robot, n)
                if "frozen" in rb["faults"]:
                    _signal_all([p for p, _ in rb["load_pids"][-n:]], signal.SIGSTOP)
            self._save()

    def remove_load(self, robot: str) -> None:
        with self._lock:
            rb = self._robot(robot)
            _signal_all([p for p, s in rb["load_pids"] if _alive(p, s) != "dead"], signal.SIGKILL)
            rb["load"], rb["load_pids"] = 0, []
            self._reap()
            self._save()

    def _live(self) -> None:
        if not self._created or self._down:
            raise TestbedError("this testbed is not up")
