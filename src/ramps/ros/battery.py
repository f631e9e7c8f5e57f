"""A robot's ROS battery topic into its ramps node's battery file.

How this works: on a ROS 2 robot the battery is a topic,
``sensor_msgs/BatteryState``; a ramps node reads its battery from a file
(``ramps node --battery-file PATH``) before each load report, and below its
reserve takes no teammates' programs and hands back those it runs. The face
(``ramps ros``) bridges the two when its ROS parameter ``battery_file`` is
set: it subscribes to ``battery_topic`` (default ``/battery_state``) and
writes each message's state of charge to that file as a fraction, renaming
a temporary file over it so the node never reads half a figure. The charge
is the message's ``percentage`` (0..1), or ``charge / capacity`` where the
driver leaves the percentage NaN; a message of a battery that is not
``present``, or that says nothing usable, writes nothing (the node then
keeps reading the last figure).

Without the ``sensor_msgs`` package the face logs one line and runs
without the bridge.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any

#: the topic a ROS robot's battery driver publishes on, by convention
DEFAULT_TOPIC = "/battery_state"


def charge_of(percentage: float, charge: float = math.nan, capacity: float = math.nan,
              present: bool = True) -> float | None:
    """A ``BatteryState``'s state of charge 0..1, or None where it gives none."""
    if not present:
        return None
    value = percentage
    if not (isinstance(value, (int, float)) and math.isfinite(value)):
        value = charge / capacity if capacity and math.isfinite(charge) and math.isfinite(capacity) else math.nan
    if not (isinstance(value, (int, float)) and math.isfinite(value)) or value < 0.0:
        return None
    return min(1.0, float(value))


def write_charge(path: str | Path, charge: float) -> None:
    """Write ``charge`` (0..1) to ``path`` whole: a temporary file renamed over it."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(f"{charge:.4f}\n")
    os.replace(tmp, path)


def bridge_battery(node: Any) -> Any:
    """Declare the face's ``battery_file`` and ``battery_topic`` parameters on
    ``node`` (an rclpy node) and, with a file named, subscribe to the topic
    and write each charge there. Returns the subscription (None: no bridge)."""
    topic = node.declare_parameter("battery_topic", DEFAULT_TOPIC).value
    path = node.declare_parameter("battery_file", "").value
    if not path:
        return None
    try:
        from sensor_msgs.msg import BatteryState
    except ImportError:
        node.get_logger().warning("battery_file is set but sensor_msgs is not installed: no battery bridge")
        return None
    last: list[float | None] = [None]

    def on_battery(msg: Any) -> None:
        charge = charge_of(msg.percentage, msg.charge, msg.capacity, msg.present)
        if charge is None or charge == last[0]:
            return
        try:
            write_charge(path, charge)
            last[0] = charge
        except OSError as exc:
            node.get_logger().warning(f"cannot write the battery file {path}: {exc}")

    node.get_logger().info(f"battery: {node.resolve_topic_name(topic)} into {path} (ramps node --battery-file)")
    return node.create_subscription(BatteryState, topic, on_battery, 10)
