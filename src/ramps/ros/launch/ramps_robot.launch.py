"""One robot's ramps for ROS 2: its ramps node and its ROS face.

    ros2 launch ramps_robot.launch.py robot:=r1 team:=warehouse connect:=tcp/192.168.1.12:7447

Needs a ROS 2 installation with the ``launch`` package (``ros2 launch``), and
ramps with the ros extra on the PATH (``pip install 'ramps-robotics[ros]'``).
Starts ``ramps node`` and ``ramps ros`` as two processes; the face submits
to this robot's node. Copy it next to your other launch files and adjust.
(Not run in ramps' CI: the launch package is not on PyPI; tests/test_ros_docs.py
runs it against a stand-in ``launch`` that records what it would start.)
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, ExecuteProcess
from launch.substitutions import LaunchConfiguration


def generate_launch_description():
    robot = LaunchConfiguration("robot")
    team = LaunchConfiguration("team")
    connect = LaunchConfiguration("connect")
    return LaunchDescription([
        DeclareLaunchArgument("robot", description="this robot's name in the team"),
        DeclareLaunchArgument("team", default_value="lab", description="ramps team name"),
        DeclareLaunchArgument("connect", default_value="",
                              description="Zenoh endpoint of a teammate, e.g. tcp/192.168.1.12:7447 ('' = multicast)"),
        DeclareLaunchArgument("commands", default_value="",
                              description="RAMPS_COMMANDS: executables as programs, NAME=PATH,NAME=PATH"),
        ExecuteProcess(
            cmd=["ramps", "node", "--robot", robot, "--team", team],
            additional_env={"RAMPS_CONNECT": connect, "RAMPS_COMMANDS": LaunchConfiguration("commands")},
            name="ramps_node", output="screen"),
        ExecuteProcess(
            cmd=["ramps", "ros", "--robot", robot, "--team", team],
            additional_env={"RAMPS_CONNECT": connect},
            name="ramps_ros", output="screen"),
    ])
