"""ramps' ROS 2 face (optional): ``pip install 'ramps-robotics[ros]'``, then ``ramps ros``.

Nothing else in ramps imports this package or rclpy: without the extra,
ramps is unchanged. ``ramps.ros.face`` holds the bridge; this module only
says whether ROS 2 can be used here and how to get it.
"""

from __future__ import annotations

INSTALL_HINT = (
    "the ROS 2 face needs rclpy and a middleware: pip install 'ramps-robotics[ros]' "
    "(ROS 2 from PyPI wheels: ros-rclpy, ros-rmw-fastrtps-cpp, ros-std-msgs, ros-action-msgs, "
    "ros-diagnostic-msgs; about 140 MB installed), or run inside a sourced ROS 2 installation that has them"
)


def missing() -> str | None:
    """None if rclpy and the message packages import here, else why not."""
    try:
        import action_msgs.msg  # noqa: F401
        import diagnostic_msgs.msg  # noqa: F401
        import rclpy  # noqa: F401
        import std_msgs.msg  # noqa: F401
    except ImportError as exc:  # rclpy without a middleware fails here too (librmw_*.so)
        return f"{INSTALL_HINT} ({exc})"
    return None
