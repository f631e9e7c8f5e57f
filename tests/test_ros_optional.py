"""The ROS 2 face is optional: without rclpy, ramps is unchanged and ``ramps ros`` says how to get it."""

from __future__ import annotations

import subprocess
import sys

import pytest

HIDE_ROS = "import sys; sys.modules['rclpy'] = None; sys.modules['std_msgs'] = None; "


def _run(code: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)


@pytest.mark.slow
def test_nothing_of_ramps_imports_rclpy() -> None:
    p = _run("import sys, ramps, ramps.cli, ramps.runtime.node, ramps.runtime.client, ramps.runtime.command, "
             "ramps.ros, ramps.ros.cli; print('rclpy' in sys.modules)")
    assert p.returncode == 0, p.stderr
    assert p.stdout.strip() == "False"


@pytest.mark.slow
def test_ramps_ros_without_the_extra_says_how_to_install_it() -> None:
    p = _run(HIDE_ROS + "from ramps.cli import main; sys.argv = ['ramps', 'ros', '--robot', 'r1']; main()")
    assert p.returncode == 2, (p.stdout, p.stderr)
    assert "pip install 'ramps-robotics[ros]'" in p.stderr
    assert "Traceback" not in p.stderr
