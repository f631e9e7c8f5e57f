"""Fault injection on a testbed's robots: the paper's failures, and undoing them.

How this works: ``Faults`` is the part of ``Testbed`` that breaks robots
(``ramps.testbed.bed`` builds and removes them). It is given the robots'
processes (``ramps.testbed.robots.RobotProcesses``) and the testbed's lock,
and sees the testbed itself through ``FaultBed``: whether it is up, its
state file, and starting and awaiting a robot's node. Every fault is
recorded in the robot's ``faults`` list and the state file, so ``ramps
testbed`` commands from another process see it and ``recover`` undoes
exactly what was done.

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
import threading
import time
from typing import Protocol

from ramps.testbed import net
from ramps.testbed.procs import TestbedError, _alive, _proc_stat, _signal_all
from ramps.testbed.robots import RobotProcesses


class FaultBed(Protocol):
    """What the faults see of their testbed (``ramps.testbed.bed.Testbed``)."""

    def _live(self) -> None:
        """Raise TestbedError unless the testbed is up."""

    def _save(self) -> None:
        """Write the state file."""

    def _start_node(self, robot: str) -> None:
        """Start the robot's node (a testbed's subclass may start another program)."""

    def wait_alive(self, robots: list[str] | None = None, timeout: float = 60.0) -> float:
        """Wait until ``robots`` are alive in the team; the seconds it took."""


class Faults:
    """Breaking and mending a testbed's robots (module docstring)."""

    def __init__(self, bed: FaultBed, procs: RobotProcesses, lock: threading.RLock) -> None:
        self.bed = bed
        self.procs = procs
        self.lock = lock

    def restart(self, robot: str, *, timeout: float = 30.0) -> float:
        """Restart the robot's node as its supervisor does (``systemctl
        restart``): SIGTERM, wait for it to leave the team (SIGKILL after
        ``timeout``), start it again with the same command (the same durable
        record), and wait until it is alive and sees the team. Returns the
        seconds from the SIGTERM until it is back."""
        t0 = time.monotonic()
        with self.lock:
            self.bed._live()
            rb = self.procs.record(robot)
            pid = rb["pid"]
            p = self.procs.popen.get(pid) if pid is not None else None
            if pid and _alive(pid, rb["start"]) != "dead":
                os.kill(pid, signal.SIGTERM)
                deadline = time.monotonic() + timeout
                while _alive(pid, rb["start"]) != "dead" and (p is None or p.poll() is None):
                    if time.monotonic() > deadline:  # what a supervisor does next
                        os.killpg(pid, signal.SIGKILL)
                        deadline = math.inf
                    time.sleep(0.05)
            self.procs.reap()
            self.bed._start_node(robot)
            self.bed._save()
        self.bed.wait_alive([robot], timeout)
        return time.monotonic() - t0

    def crash(self, robot: str) -> None:
        """SIGKILL the robot's node, workers and load (a power cut)."""
        with self.lock:
            self.bed._live()
            rb = self.procs.record(robot)
            self.procs.kill(robot)
            rb["faults"] = [f for f in rb["faults"] if f != "frozen"] + ["crashed"] * ("crashed" not in rb["faults"])
            rb["load_pids"] = []
            self.bed._save()

    def cut(self, robot: str) -> None:
        """Take the robot's network link down; its processes keep running."""
        with self.lock:
            self.bed._live()
            rb = self.procs.record(robot)
            net.link_down(rb["ns"])
            if "cut" not in rb["faults"]:
                rb["faults"].append("cut")
            self.bed._save()

    def lossy(self, robot: str, loss: float) -> None:
        """Drop each of the robot's packets, in and out, with probability
        ``loss`` (a poor WiFi link; TCP retransmits, so keep-alives arrive
        late rather than never). ``loss=0`` or ``recover`` ends it."""
        with self.lock:
            self.bed._live()
            rb = self.procs.record(robot)
            net.set_loss(rb["ns"], loss)
            rb["faults"] = [f for f in rb["faults"] if f != "lossy"] + ["lossy"] * (loss > 0)
            self.bed._save()

    def freeze(self, robot: str) -> None:
        """SIGSTOP every process of the robot (sockets stay open, nothing answers)."""
        with self.lock:
            self.bed._live()
            rb = self.procs.record(robot)
            if "crashed" in rb["faults"]:
                raise TestbedError(f"robot {robot} is crashed; recover it before freezing it")
            if rb["pid"]:
                try:
                    os.killpg(rb["pid"], signal.SIGSTOP)
                except ProcessLookupError:
                    pass
            deadline = time.monotonic() + 2.0
            while True:  # until every process is stopped (signals are delivered asynchronously)
                running = [p for p in self.procs.pids(robot) if (_proc_stat(p) or ("T", 0))[0] not in ("T", "t")]
                if not running or time.monotonic() > deadline:
                    break
                _signal_all(running, signal.SIGSTOP)
                time.sleep(0.005)
            if "frozen" not in rb["faults"]:
                rb["faults"].append("frozen")
            self.bed._save()

    def recover(self, robot: str, *, wait: bool = True, timeout: float = 30.0) -> list[str]:
        """Undo every fault of the robot (link up, SIGCONT, restart a crashed
        node and its load); with ``wait``, until the root namespace sees it alive
        again. Returns the faults undone."""
        with self.lock:
            self.bed._live()
            rb = self.procs.record(robot)
            undone = list(rb["faults"])
            if "cut" in undone or net.link_state(rb["ns"]) != "up":
                net.link_up(rb["ns"])
            if "lossy" in undone:
                net.set_loss(rb["ns"], 0)
            if "frozen" in undone:
                _signal_all(self.procs.pids(robot), signal.SIGCONT)
                if rb["pid"]:
                    try:
                        os.killpg(rb["pid"], signal.SIGCONT)
                    except ProcessLookupError:
                        pass
            if "crashed" in undone or self.procs.state(robot) == "dead":
                self.procs.kill(robot)  # leftovers of the old incarnation, if any
                rb["load_pids"] = []
                self.bed._start_node(robot)
                self.procs.start_load(robot, rb["load"])
            rb["faults"] = []
            self.bed._save()
        if wait:
            self.bed.wait_alive([robot], timeout)
        return undone

    def add_load(self, robot: str, n: int = 1) -> None:
        """Start ``n`` busy processes inside the robot (its namespace and cgroup)."""
        if n < 0:
            raise ValueError("n must be >= 0")
        with self.lock:
            self.bed._live()
            rb = self.procs.record(robot)
            rb["load"] += n
            if "crashed" not in rb["faults"]:
                self.procs.start_load(robot, n)
                if "frozen" in rb["faults"]:
                    _signal_all([p for p, _ in rb["load_pids"][-n:]], signal.SIGSTOP)
            self.bed._save()

    def remove_load(self, robot: str) -> None:
        with self.lock:
            rb = self.procs.record(robot)
            _signal_all([p for p, s in rb["load_pids"] if _alive(p, s) != "dead"], signal.SIGKILL)
            rb["load"], rb["load_pids"] = 0, []
            self.procs.reap()
            self.bed._save()
