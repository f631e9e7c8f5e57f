"""The testbed's parts without a testbed: no root, no namespaces, no processes."""

from __future__ import annotations

import signal
import threading
from types import FrameType

import pytest

from ramps.testbed.exits import DownOnExit
from ramps.testbed.faults import Faults
from ramps.testbed.procs import TestbedError
from ramps.testbed.robots import RobotProcesses, check_robots


def test_down_on_exit_runs_down_then_the_previous_handler_and_puts_it_back() -> None:
    calls: list[str] = []

    def previous(signum: int, frame: FrameType | None) -> None:
        calls.append(f"previous {signum}")

    old = signal.signal(signal.SIGTERM, previous)
    try:
        exits = DownOnExit(lambda: calls.append("down"))
        exits.install()
        handler = signal.getsignal(signal.SIGTERM)
        assert callable(handler) and handler is not previous
        handler(signal.SIGTERM, None)
        assert calls == ["down", f"previous {int(signal.SIGTERM)}"]
        exits.release()
        assert signal.getsignal(signal.SIGTERM) is previous
    finally:
        signal.signal(signal.SIGTERM, old)


def test_robot_names_and_their_mistakes() -> None:
    assert check_robots(3, "both", {}, {}) == ["r1", "r2", "r3"]
    with pytest.raises(ValueError, match="at least one robot"):
        check_robots([], "both", {}, {})
    with pytest.raises(ValueError, match="discovery"):
        check_robots(2, "gossip", {}, {})
    with pytest.raises(ValueError, match="loaded robot 'r9' is not one of r1, r2"):
        check_robots(2, "both", {"r9": 1}, {})
    with pytest.raises(ValueError, match="robot_config names 'r9'"):
        check_robots(2, "both", {}, {"r9": {}})


class _NotUp:
    """A testbed that is down: its faults must refuse before touching anything."""

    def _live(self) -> None:
        raise TestbedError("this testbed is not up")

    def _save(self) -> None:
        raise AssertionError("nothing to save")

    def _start_node(self, robot: str) -> None:
        raise AssertionError("nothing to start")

    def wait_alive(self, robots: list[str] | None = None, timeout: float = 60.0) -> float:
        raise AssertionError("nothing to wait for")


def test_faults_refuse_a_testbed_that_is_not_up_and_an_unknown_robot() -> None:
    procs = RobotProcesses({}, "v1", "python3", {})
    faults = Faults(_NotUp(), procs, threading.RLock())
    for fault in (faults.crash, faults.cut, faults.freeze):
        with pytest.raises(TestbedError, match="not up"):
            fault("r1")
    with pytest.raises(TestbedError, match="unknown robot 'r1'; this testbed has none up"):
        procs.record("r1")
