"""The ROS 2 face as the launch file and docs/ros2.md name it, checked without
a ROS 2 installation (``launch`` and the ``ros2`` command line are not on
PyPI, so neither runs here).

- ``ramps_robot.launch.py`` runs against a stand-in ``launch`` package (stdlib
  only) that records what it would start: the docs' ``ros2 launch`` lines give
  its declared arguments, each process is a ``ramps`` command the real CLI
  parses, and its environment is read by the node's settings as meant, empty
  arguments included.
- every ``ros2 topic`` and ``ros2 action`` line of the docs names a topic or
  action that a real face (``RosFace`` over the in-memory team) has, of the
  type it has there, with a payload of that type's fields and a registered
  program with arguments it takes. Skipped without the ``ros`` extra.
"""

from __future__ import annotations

import importlib
import json
import random
import runpy
import shlex
import sys
import time
import tomllib
import types
import uuid
from pathlib import Path
from typing import Any

import pytest
from test_docs_commands import PAGES, cli, commands, shell_blocks

from ramps.runtime.registry import BUILTINS
from ramps.runtime.settings import _ENV, load_settings

ROOT = Path(__file__).resolve().parents[1]
LAUNCH_FILE = ROOT / "src/ramps/ros/launch/ramps_robot.launch.py"


def ros2_lines(sub: str) -> list[tuple[str, list[str]]]:
    """Every ``ros2 SUB ...`` command of the docs' shell blocks and of the
    launch file's docstring, with where it is."""
    found = []
    for page in PAGES:
        for block in shell_blocks(page):
            found += [(block.id, w) for w in commands(block.text) if w[:2] == ["ros2", sub]]
    doc = LAUNCH_FILE.read_text().split('"""')[1]
    example = "\n".join(line.strip() for line in doc.splitlines() if line.strip().startswith("ros2 "))
    found += [(LAUNCH_FILE.name, w) for w in commands(example) if w[:2] == ["ros2", sub]]
    return found


# ------------------------------------------------------------------ the launch file
class LaunchConfiguration:
    def __init__(self, variable_name: str, *, default: Any = None) -> None:
        self.name, self.default = variable_name, default


class DeclareLaunchArgument:
    def __init__(self, name: str, *, default_value: str | None = None, description: str | None = None,
                 choices: list[str] | None = None) -> None:
        self.name, self.default, self.description = name, default_value, description


class ExecuteProcess:
    #: launch.actions.ExecuteProcess's other keywords (ros2/launch, rolling)
    OTHER = {"cwd", "env", "shell", "sigterm_timeout", "sigkill_timeout", "emulate_tty", "prefix", "output_format",
             "log_cmd", "on_exit", "respawn", "respawn_delay", "condition"}

    def __init__(self, *, cmd: list[Any], name: Any = None, additional_env: dict[str, Any] | None = None,
                 output: str = "log", **other: Any) -> None:
        assert set(other) <= self.OTHER, f"ExecuteProcess has no {sorted(set(other) - self.OTHER)}"
        self.cmd, self.name, self.additional_env, self.other = cmd, name, additional_env or {}, other


class LaunchDescription:
    def __init__(self, initial_entities: list[Any] | None = None) -> None:
        self.entities = list(initial_entities or [])


@pytest.fixture
def described(monkeypatch: pytest.MonkeyPatch) -> LaunchDescription:
    """The launch file's description, made with the stand-in ``launch``."""
    contents = {"launch": [LaunchDescription], "launch.actions": [DeclareLaunchArgument, ExecuteProcess],
                "launch.substitutions": [LaunchConfiguration]}
    for name, classes in contents.items():
        module = types.ModuleType(name)
        for cls in classes:
            setattr(module, cls.__name__, cls)
        monkeypatch.setitem(sys.modules, name, module)
    return runpy.run_path(str(LAUNCH_FILE))["generate_launch_description"]()


def resolve(value: Any, declared: dict[str, DeclareLaunchArgument], given: dict[str, str]) -> str:
    """A launch value as ``ros2 launch ... NAME:=VALUE`` makes it."""
    if not isinstance(value, LaunchConfiguration):
        return value
    assert value.name in declared, f"LaunchConfiguration({value.name!r}) is no declared argument"
    if value.name in given:
        return given[value.name]
    assert declared[value.name].default is not None, f"launch argument {value.name!r} has no default: give it"
    return declared[value.name].default


def processes(desc: LaunchDescription, given: dict[str, str]) -> dict[str, tuple[list[str], dict[str, str]]]:
    """Each process the launch starts: its command line and added environment."""
    declared = {a.name: a for a in desc.entities if isinstance(a, DeclareLaunchArgument)}
    assert set(given) <= set(declared), f"not declared by the launch file: {sorted(set(given) - set(declared))}"
    return {p.name: ([resolve(w, declared, given) for w in p.cmd],
                     {k: resolve(v, declared, given) for k, v in p.additional_env.items()})
            for p in desc.entities if isinstance(p, ExecuteProcess)}


def parse(words: list[str]) -> dict[str, Any]:
    """``ramps SUB ARGS`` parsed by the real CLI (nothing runs): its values."""
    scripts = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["scripts"]
    assert words[0] in scripts, f"{words[0]!r} is no console script of the package ({', '.join(scripts)})"
    command = cli().commands[words[1]]
    with command.make_context(f"ramps {words[1]}", list(words[2:])) as ctx:
        return dict(ctx.params)


def test_the_docs_launch_lines_start_the_node_and_the_face_they_mean(described: LaunchDescription) -> None:
    lines = ros2_lines("launch")
    assert len(lines) >= 2, lines  # docs/ros2.md and the file's own docstring
    for where, words in lines:
        assert Path(words[2]).name == LAUNCH_FILE.name, (where, words)
        given = dict(w.split(":=", 1) for w in words[3:])
        started = processes(described, given)
        assert set(started) == {"ramps_node", "ramps_ros"}, where
        (node_cmd, node_env), (ros_cmd, ros_env) = started["ramps_node"], started["ramps_ros"]
        assert node_cmd[:2] == ["ramps", "node"] and ros_cmd[:2] == ["ramps", "ros"], where
        assert set(node_env) | set(ros_env) <= set(_ENV), f"{where}: environment no setting reads"
        node = parse(node_cmd)
        s = load_settings(flags={k: node[k] for k in ("robot", "team")}, environ=node_env)
        assert (s.robot, s.team, s.connect) == (given["robot"], given["team"], [given["connect"]]), where
        assert s.commands.keys() == {c.split("=", 1)[0] for c in given.get("commands", "").split(",") if c}, where
        face = parse(ros_cmd)
        face_env = load_settings(flags={}, environ=ros_env, default_robot=False)
        # the face submits to this robot's node, in this robot's namespace (/r1: the docs' topics)
        assert (face["robot"], face["team"], face_env.connect) == (s.robot, s.team, s.connect), where


def test_the_launch_file_s_defaults_leave_discovery_and_commands_to_the_node(described: LaunchDescription) -> None:
    """``robot:=r1`` alone: the empty ``connect`` and ``commands`` defaults
    reach the node as empty variables, which mean none (multicast finds the
    team), not an endpoint or a command named ''."""
    started = processes(described, {"robot": "r1"})
    node_cmd, node_env = started["ramps_node"]
    node = parse(node_cmd)
    s = load_settings(flags={k: node[k] for k in ("robot", "team")}, environ=node_env)
    assert (s.robot, s.team, s.connect, s.multicast, s.commands) == ("r1", "lab", [], True, {})
    with pytest.raises(AssertionError, match="'robot' has no default"):
        processes(described, {})


# ------------------------------------------------------------------ the ros2 command lines
def _type_name(cls: type) -> str:
    """``std_msgs.msg._string.String`` -> ``std_msgs/msg/String``."""
    package, kind = cls.__module__.split(".")[:2]
    return f"{package}/{kind}/{cls.__name__}"


@pytest.fixture
def face(monkeypatch: pytest.MonkeyPatch):
    """A real face in /r1 (what ``ramps ros --robot r1`` makes) over the
    in-memory team, on a private ROS graph: its topics and action, by name."""
    rclpy = pytest.importorskip("rclpy", reason="the ros extra is not installed (pip install 'ramps-robotics[ros]')")
    from ramps.ros import missing

    if missing() is not None:
        pytest.skip(missing())
    import ramps.ros.face as face_mod
    from ramps.testing.memory import MemoryTeam

    monkeypatch.setenv("ROS_DOMAIN_ID", str(random.Random(uuid.uuid4().int).randint(101, 200)))
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    mem = MemoryTeam({"r1": (1, 1.0)}, team="mem-ros-docs")
    mem.run(1.0)
    rclpy.init()
    client = mem.connect("r1")
    f = face_mod.RosFace(namespace="/" + face_mod.ros_name("r1"), overrides={}, team=client)
    try:
        yield f
    finally:
        f.close()
        rclpy.try_shutdown()
        mem.close()


def _graph(face: Any) -> dict[str, dict[str, str]]:
    """The face's topics and actions as ``ros2 topic/action list -t`` shows
    them (waiting for the graph to list its own entities)."""
    from rclpy.action import get_action_server_names_and_types_by_node

    name, ns = face.get_name(), face.get_namespace()
    end = time.monotonic() + 10
    while True:
        graph = {kind: {topic: types_[0] for topic, types_ in listed}
                 for kind, listed in (("pub", face.get_publisher_names_and_types_by_node(name, ns)),
                                      ("sub", face.get_subscriber_names_and_types_by_node(name, ns)),
                                      ("action", get_action_server_names_and_types_by_node(face, name, ns)))}
        if (graph["pub"] and graph["sub"] and (graph["action"] or face.action_server is None)) \
                or time.monotonic() > end:
            return graph
        time.sleep(0.05)


def _interface(type_name: str) -> Any:
    """``std_msgs/msg/String`` -> its Python class, as ``ros2`` loads it."""
    package, kind, name = type_name.split("/")
    return getattr(importlib.import_module(f"{package}.{kind}"), name)


def _check_goal(where: str, program: str, args: dict[str, Any]) -> None:
    assert program in BUILTINS, f"{where}: {program!r} is no built-in program"
    try:
        BUILTINS[program].check_args(args)
    except TypeError as exc:
        raise AssertionError(f"{where}: {program} refuses these arguments: {exc}") from None


def test_every_ros2_line_of_the_docs_names_what_the_face_has(face: Any) -> None:
    import yaml  # with the ros extra, as for the ros2 command line that reads these payloads
    graph = _graph(face)
    assert graph["action"] == ({"/r1/ramps/run": "ramps_interfaces/action/RunProgram"}
                               if face.action_server is not None else {}), graph
    lines = [*ros2_lines("topic"), *ros2_lines("action")]
    assert len(lines) >= 6, lines
    for where, words in lines:
        where = f"{where}: {shlex.join(words)}"
        rest = [w for w in words[3:] if not w.startswith("-")]
        if words[1:3] == ["topic", "echo"]:
            assert rest[0] in graph["pub"], f"{where}: the face publishes no {rest[0]} ({sorted(graph['pub'])})"
        elif words[1:3] == ["topic", "pub"]:
            topic, type_name, payload = rest
            assert graph["sub"].get(topic) == type_name, f"{where}: the face hears {graph['sub']}"
            message = _interface(type_name)
            fields = yaml.safe_load(payload)
            assert set(fields) <= set(message.get_fields_and_field_types()), where
            if topic.endswith("/goal"):
                goal = json.loads(fields["data"])
                _check_goal(where, goal["program"], goal.get("args", {}))
        elif words[1:3] == ["action", "send_goal"]:
            action, type_name, payload = rest
            if face.action_server is not None:
                assert graph["action"].get(action) == type_name, f"{where}: the face serves {graph['action']}"
            else:
                assert (action, type_name) == ("/r1/ramps/run", "ramps_interfaces/action/RunProgram"), where
                continue
            fields = yaml.safe_load(payload)
            assert set(fields) <= set(_interface(type_name).Goal.get_fields_and_field_types()), where
            _check_goal(where, fields["program"], json.loads(fields.get("args_json", "{}")))
        else:
            raise AssertionError(f"{where}: a ros2 line this test does not check yet")
