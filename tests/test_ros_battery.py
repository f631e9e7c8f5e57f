"""The face's battery bridge (``ramps.ros.battery``) without ROS: a
``sensor_msgs/BatteryState``'s charge, written whole for the node's battery
file, and the bridge on a stand-in rclpy node and message type."""

from __future__ import annotations

import math
import sys
import types
from pathlib import Path

import pytest

from ramps.ros.battery import DEFAULT_TOPIC, bridge_battery, charge_of, write_charge
from ramps.runtime.battery import parse_charge


@pytest.mark.parametrize("args, charge", [((0.87,), 0.87), ((math.nan, 2.0, 4.0), 0.5), ((1.2,), 1.0),
                                          ((math.nan,), None), ((math.nan, 1.0, 0.0), None), ((-0.1,), None),
                                          ((0.5, math.nan, math.nan, False), None)])
def test_the_charge_of_a_battery_state(args, charge) -> None:
    assert charge_of(*args) == (None if charge is None else pytest.approx(charge))


def test_a_charge_is_written_whole_and_the_node_reads_it_as_a_fraction(tmp_path: Path) -> None:
    path = tmp_path / "battery-r1"
    for charge in (0.0, 0.005, 0.42, 1.0):
        write_charge(path, charge)
        assert parse_charge(path.read_text()) == pytest.approx(charge, abs=1e-4)
    assert [p.name for p in tmp_path.iterdir()] == ["battery-r1"]


class _Node:
    def __init__(self, params: dict) -> None:
        self.params, self.subs, self.logged = params, [], []

    def declare_parameter(self, name: str, default):
        return types.SimpleNamespace(value=self.params.get(name, default))

    def get_logger(self):
        return types.SimpleNamespace(info=self.logged.append, warning=self.logged.append)

    def resolve_topic_name(self, topic: str) -> str:
        return topic

    def create_subscription(self, kind, topic, callback, depth):
        self.subs.append((kind, topic, callback))
        return (kind, topic)


def test_the_bridge_writes_each_new_charge_and_is_off_without_a_file(tmp_path: Path, monkeypatch) -> None:
    assert bridge_battery(_Node({})) is None
    msgs = types.ModuleType("sensor_msgs.msg")
    msgs.BatteryState = type("BatteryState", (), {})
    monkeypatch.setitem(sys.modules, "sensor_msgs", types.ModuleType("sensor_msgs"))
    monkeypatch.setitem(sys.modules, "sensor_msgs.msg", msgs)
    path = tmp_path / "battery"
    node = _Node({"battery_file": str(path)})
    assert bridge_battery(node) == (msgs.BatteryState, DEFAULT_TOPIC)
    [(_, _, on_battery)] = node.subs
    on_battery(types.SimpleNamespace(percentage=0.64, charge=math.nan, capacity=math.nan, present=True))
    assert path.read_text() == "0.6400\n"
    on_battery(types.SimpleNamespace(percentage=math.nan, charge=math.nan, capacity=math.nan, present=True))
    assert path.read_text() == "0.6400\n"  # nothing said: the last figure stays


def test_without_sensor_msgs_the_face_runs_without_the_bridge(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setitem(sys.modules, "sensor_msgs", None)
    node = _Node({"battery_file": str(tmp_path / "b")})
    assert bridge_battery(node) is None and "sensor_msgs is not installed" in node.logged[0]
