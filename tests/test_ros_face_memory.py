"""The ROS 2 face (``ramps ros``) in one process: real rclpy, the real face,
the real client and nodes over the in-memory team (``ramps.testing.memory``).
What a ROS engineer meets first: ``--ros-args`` is ROS's (``-r __ns:=/r1``
is a remapping, not ``--robot``), ``RAMPS_TEAM`` and the rest of the
environment count, and feedback states are the documented ones, progress
coming as ``running`` feedback. Skipped without the ``ros`` extra."""

from __future__ import annotations

import json
import random
import re
import sys
import time
import uuid
from pathlib import Path

import pytest
from typer.testing import CliRunner

rclpy = pytest.importorskip("rclpy", reason="the ros extra is not installed (pip install 'ramps-robotics[ros]')")
from ramps.ros import missing  # noqa: E402

if missing() is not None:
    pytest.skip(missing(), allow_module_level=True)

from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402
from std_msgs.msg import String  # noqa: E402

import ramps.ros.face as face_mod  # noqa: E402
from ramps.cli import app  # noqa: E402
from ramps.testing.memory import MemoryTeam  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
RELIABLE = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)


@pytest.fixture
def ros(monkeypatch):
    """rclpy on a private graph (a domain of its own, this host only), shut down after."""
    monkeypatch.setenv("ROS_DOMAIN_ID", str(random.Random(uuid.uuid4().int).randint(101, 200)))
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    yield
    rclpy.try_shutdown()


@pytest.fixture
def mem():
    t = MemoryTeam({"r1": (1, 1.0), "r2": (4, 4.0)}, team="mem-ros")
    t.run(3.0)
    yield t
    t.close()


def test_everything_from_ros_args_on_is_ros_s(ros, mem, monkeypatch):
    seen = {}
    monkeypatch.setattr(face_mod, "run", lambda **kw: seen.update(kw))
    runner = CliRunner()
    res = runner.invoke(app, ["ros", "--team", "mem-ros", "--goal-timeout", "30", "--connect-timeout", "4",
                              "--ros-args", "-p", "diagnostics_period:=2.5", "-r", "__ns:=/r1"])
    assert res.exit_code == 0, res.output
    # -r went to ROS, not to --robot
    assert seen["overrides"] == {"team": "mem-ros", "goal_timeout": 30.0, "connect_timeout": 4.0}
    assert seen["ros_args"] == ["--ros-args", "-p", "diagnostics_period:=2.5", "-r", "__ns:=/r1"]
    assert seen["namespace"] == ""
    typo = runner.invoke(app, ["ros", "--tema", "x"])  # before --ros-args: ramps' options only
    assert typo.exit_code == 2 and "no such option or argument: --tema x" in typo.output
    # what ROS makes of them: the face in /r1 with the parameter given
    rclpy.init(args=["ramps-ros", *seen["ros_args"]])
    client = mem.connect("r1")
    face = face_mod.RosFace(namespace=seen["namespace"], overrides=seen["overrides"], team=client)
    try:
        assert face.get_namespace() == "/r1" and face.params["diagnostics_period"] == 2.5
        assert (face.params["goal_timeout"], face.params["connect_timeout"]) == (30.0, 4.0)
        assert face.resolve_topic_name("~/goal") == "/r1/ramps/goal"
    finally:
        face.close()


def test_ramps_team_and_the_environment_count(ros, mem, monkeypatch):
    monkeypatch.setenv("RAMPS_TEAM", "mem-ros")
    monkeypatch.setenv("RAMPS_MULTICAST", "0")
    opened = []

    def memory_session(settings, **_):  # the face's ramps.connect() reaches the memory team
        opened.append(settings)
        return mem.bus.transport(f"face-{len(opened)}")

    monkeypatch.setattr("ramps.runtime.client.ZenohTransport.open", memory_session)
    rclpy.init()
    face = face_mod.RosFace(namespace="/r1", overrides={"connect_timeout": 2.0})
    try:
        assert face.team.team == "mem-ros" and face.origin in ("r1", "r2")
        [settings] = opened
        assert settings.team == "mem-ros" and settings.multicast is False
        assert face.params["team"] is None and face.params["multicast"] is None  # not given: the environment's
    finally:
        face.close()
    with pytest.raises(ValueError, match="ROS parameter 'multicast' must be true or false"):
        face_mod.RosFace(namespace="/r1", overrides={"multicast": "sometimes"})


def _documented_states(text: str) -> set[str]:
    m = re.search(r"string state\s+# ([a-z_, ]+)\n", text)
    assert m, "no feedback state comment"
    return {s.strip() for s in m.group(1).split(",")}


def test_feedback_states_are_the_documented_ones_and_progress_comes_as_running(ros, mem):
    emitted = {"accepted", *face_mod._FUTURE_STATES.values()}  # what the face can send: accepted, then the future's
    for doc in (ROOT / "src/ramps/ros/interfaces/RunProgram.action", ROOT / "docs/ros2.md"):
        assert _documented_states(doc.read_text()) == emitted, doc
    rclpy.init()
    client = mem.connect("r1")
    face = face_mod.RosFace(namespace="/r1", overrides={}, team=client)
    user = rclpy.create_node("user")
    feedback: list[dict] = []
    results: list[dict] = []
    user.create_subscription(String, "/r1/ramps/feedback", lambda m: feedback.append(json.loads(m.data)), RELIABLE)
    user.create_subscription(String, "/r1/ramps/result", lambda m: results.append(json.loads(m.data)), RELIABLE)
    goals = user.create_publisher(String, "/r1/ramps/goal", RELIABLE)
    ex = SingleThreadedExecutor()
    ex.add_node(face)
    ex.add_node(user)

    def spin_until(cond, what: str, timeout: float = 20.0) -> None:
        end = time.monotonic() + timeout
        while not cond():
            assert time.monotonic() < end, f"{what}; feedback {feedback}, results {results}"
            ex.spin_once(timeout_sec=0.02)

    try:
        spin_until(lambda: goals.get_subscription_count() > 0 and face.pub_feedback.get_subscription_count() > 0,
                   "the face and the user matched")
        goals.publish(String(data=json.dumps({"goal_id": "g1", "program": "echo", "args": {"x": 1}})))
        spin_until(lambda: "g1" in face._goals and face._goals["g1"].fut is not None, "the goal submitted")
        mem.run(2.0, complete=False, until=lambda: any(p.jobs for p in mem.pools.values()))
        host = next(name for name, p in mem.pools.items() if p.jobs)
        [key] = list(mem.pools[host].jobs)
        mem.nodes[host].inbound.progress_reported(key, 0.5, "half way")  # as the worker reports it
        mem.run(0.5, complete=False)
        spin_until(lambda: any(f["progress"] == 0.5 for f in feedback), "progress feedback")
        mem.run(5.0)
        spin_until(lambda: results, "the result")
        assert results[0]["ok"] and results[0]["value"] == {"x": 1}
        assert {f["state"] for f in feedback} <= emitted
        [news] = [f for f in feedback if f["progress"] == 0.5]
        assert (news["state"], news["host"], news["detail"]) == ("running", host, "half way")
    finally:
        ex.shutdown()
        user.destroy_node()
        face.close()


if __name__ == "__main__":  # pragma: no cover
    sys.exit(pytest.main([__file__, "-q"]))
