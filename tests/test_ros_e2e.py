"""End to end with real ROS 2: a plain rclpy client uses a 3-robot team through ``ramps ros``.

Skipped when the ``ros`` extra (rclpy from the PyPI wheels) is not installed.
The test's ROS graph is private: a ROS domain id of its own and discovery
limited to this host. The ROS user's side below is plain rclpy with standard
message types (std_msgs/String goals and results carrying JSON,
diagnostic_msgs/DiagnosticArray), written as a ROS user would.
"""

from __future__ import annotations

import json
import os
import random
import sys
import time
import uuid

import psutil
import pytest
from runtime_team import LocalTeam, assert_no_leftovers

rclpy = pytest.importorskip("rclpy", reason="the ros extra is not installed (pip install 'ramps-robotics[ros]')")
from ramps.ros import missing  # noqa: E402

if missing() is not None:
    pytest.skip(missing(), allow_module_level=True)

from action_msgs.msg import GoalStatus, GoalStatusArray  # noqa: E402
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus  # noqa: E402
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from std_msgs.msg import String  # noqa: E402

pytestmark = pytest.mark.slow

WAIT = 60.0
RELIABLE = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
LATCHED = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)


@pytest.fixture(scope="module", autouse=True)
def private_ros_graph():
    """A domain of our own, discovery on this host only; restored after."""
    saved = {k: os.environ.get(k) for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE")}
    os.environ["ROS_DOMAIN_ID"] = str(random.Random(uuid.uuid4().int).randint(1, 100))
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    rclpy.init()
    yield
    rclpy.try_shutdown()
    for k, v in saved.items():
        if v is None:
            os.environ.pop(k, None)
        else:
            os.environ[k] = v
    assert_no_leftovers()


class StepperTeam(LocalTeam):
    def start_node(self, name, cores=None, extra_env=None, *, wait=True, extra_args=None):
        return super().start_node(name, cores, extra_env, wait=wait,
                                  extra_args=["--program", "e2e_progress_progs:stepper"] + (extra_args or []))


class RosUser:
    """What a ROS engineer writes: publishers for goals and cancels, subscribers for the rest."""

    def __init__(self, robot: str = "r1") -> None:
        self.node = rclpy.create_node(f"user_{uuid.uuid4().hex[:6]}")
        base = f"/{robot}/ramps"
        self.goal = self.node.create_publisher(String, f"{base}/goal", RELIABLE)
        self.cancel_pub = self.node.create_publisher(String, f"{base}/cancel", RELIABLE)
        self.feedback: list[dict] = []
        self.results: dict[str, dict] = {}
        self.status: dict[bytes, int] = {}
        self.diagnostics: list[DiagnosticArray] = []
        self.node.create_subscription(String, f"{base}/feedback", lambda m: self.feedback.append(json.loads(m.data)),
                                      RELIABLE)
        self.node.create_subscription(String, f"{base}/result", self._on_result, LATCHED)
        self.node.create_subscription(GoalStatusArray, f"{base}/status", self._on_status,
                                      QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                                                 durability=DurabilityPolicy.TRANSIENT_LOCAL))
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self.diagnostics.append, RELIABLE)

    def _on_result(self, m: String) -> None:
        r = json.loads(m.data)
        self.results[r["goal_id"]] = r

    def _on_status(self, m: GoalStatusArray) -> None:
        for s in m.status_list:
            self.status[bytes(s.goal_info.goal_id.uuid)] = s.status

    def spin_until(self, pred, what: str, timeout: float = WAIT):
        deadline = time.monotonic() + timeout
        while True:
            rclpy.spin_once(self.node, timeout_sec=0.05)
            v = pred()
            if v:
                return v
            if time.monotonic() > deadline:
                raise AssertionError(f"timed out after {timeout:g} s waiting for {what}")

    def send(self, goal_id: str, program: str, policy: str = "", **args) -> None:
        self.goal.publish(String(data=json.dumps({"goal_id": goal_id, "program": program, "args": args,
                                                  "policy": policy})))

    def cancel(self, goal_id: str) -> None:
        self.cancel_pub.publish(String(data=goal_id))

    def of(self, goal_id: str) -> list[dict]:
        return [f for f in self.feedback if f["goal_id"] == goal_id]


@pytest.fixture(scope="module")
def team(tmp_path_factory):
    """Three robots and r1's ROS face, shared; the last test kills robots."""
    with StepperTeam(3, tmp_path_factory.mktemp("rosteam"), cores=1) as t:
        face = start_face(t)
        try:
            yield t
        finally:
            face.terminate()
            face.wait(20)


@pytest.fixture(scope="module")
def user(team):
    u = RosUser("r1")
    u.spin_until(lambda: u.goal.get_subscription_count() > 0, "the ramps ROS face to appear")
    yield u
    u.node.destroy_node()


def _gone(pid: int) -> bool:
    """The process exited (or is a zombie): it may exit between two looks at it."""
    try:
        return psutil.Process(pid).status() == psutil.STATUS_ZOMBIE
    except psutil.NoSuchProcess:
        return True


def start_face(t: LocalTeam, robot: str = "r1"):
    return t.spawn([sys.executable, "-m", "ramps.cli", "ros", "--team", t.team, "--robot", robot,
                    "--no-multicast", "--diagnostics-period", "0.5", "--origin-grace", "3",
                    *sum((["--connect", e] for e in t.endpoints()), [])],
                   name=f"rosface-{robot}")


def test_rclpy_client_runs_programs_sees_feedback_and_cancels(team, user):
    t = team
    user.spin_until(lambda: user.diagnostics, "/diagnostics")
    # a subscriber sees every robot's load on /diagnostics
    names = user.spin_until(lambda: {s.name for a in user.diagnostics[-3:] for s in a.status
                                     if s.level == DiagnosticStatus.OK} >= {"ramps: r1", "ramps: r2", "ramps: r3"},
                            "every robot OK on /diagnostics")
    assert names
    last = user.diagnostics[-1]
    r2 = next(s for s in last.status if s.name == "ramps: r2")
    assert {kv.key for kv in r2.values} >= {"cores", "cpu busy", "run queue", "programs running", "programs moved",
                                            "node cores"}
    assert 0.0 <= float(dict((kv.key, kv.value) for kv in r2.values)["node cores"]) <= 1.0
    assert dict((kv.key, kv.value) for kv in r2.values)["cores"] == "1"
    # goals: every one gets its result, with feedback naming host and progress
    for i in range(4):
        user.send(f"g{i}", "stepper", steps=4, dt=0.3)
    user.send("w", "where", x=5)
    user.send("bad", "no_such_program")
    user.goal.publish(String(data="{not json"))
    user.spin_until(lambda: all(g in user.results for g in ("g0", "g1", "g2", "g3", "w", "bad")),
                    "every goal's result")
    for i in range(4):
        r = user.results[f"g{i}"]
        assert r["ok"] and r["value"]["steps"] == 4 and r["host"] == r["value"]["robot"], r
        fb = user.of(f"g{i}")
        assert any(f["state"] == "running" and f["host"] in ("r1", "r2", "r3") for f in fb), fb
        assert any(f["progress"] is not None and 0 < f["progress"] <= 1 for f in fb), fb
    assert user.results["w"]["ok"] and user.results["w"]["value"]["x"] == 5
    assert not user.results["bad"]["ok"] and user.results["bad"]["error_kind"] == "refused"
    assert "no_such_program" in user.results["bad"]["error"]
    user.spin_until(lambda: user.status.get(uuid.uuid5(uuid.NAMESPACE_URL, "ramps:g0").bytes)
                    == GoalStatus.STATUS_SUCCEEDED, "g0 SUCCEEDED on the status topic")
    # cancelling a goal withdraws its program: its worker process goes
    user.send("long", "sleepy", seconds=120, tag="rosc")
    mark = t.marks / "rosc"
    user.spin_until(lambda: mark.exists(), "the long goal to start")
    robot, pid = mark.read_text().split()
    pid = int(pid)
    user.cancel("long")
    r = user.spin_until(lambda: user.results.get("long"), "the cancelled goal's result")
    assert not r["ok"] and r["error_kind"] == "cancelled", r
    user.spin_until(lambda: _gone(pid),
                    f"the worker running the withdrawn program on {robot} to go")
    user.spin_until(lambda: user.status.get(uuid.uuid5(uuid.NAMESPACE_URL, "ramps:long").bytes)
                    == GoalStatus.STATUS_CANCELED, "the long goal CANCELED on the status topic")


def test_run_program_action_with_an_rclpy_action_client(team, user):
    """The real ROS 2 action (ramps_interfaces/action/RunProgram, built by ramps ros --build-interfaces)."""
    try:
        from ramps_interfaces.action import RunProgram
    except ImportError:
        pytest.skip("ramps_interfaces is not built here: ramps ros --build-interfaces (make test does it)")
    from rclpy.action import ActionClient

    client = ActionClient(user.node, RunProgram, "/r1/ramps/run")
    user.spin_until(lambda: client.server_is_ready(), "the RunProgram action server")
    feedback: dict[str, list] = {}

    def send(name: str, program: str, **args):
        fut = client.send_goal_async(RunProgram.Goal(program=program, args_json=json.dumps(args)),
                                     feedback_callback=lambda m: feedback.setdefault(name, []).append(m.feedback))
        handle = user.spin_until(lambda: fut.result() if fut.done() else None, f"goal {name} accepted")
        assert handle.accepted
        return handle

    handles = {f"a{i}": send(f"a{i}", "stepper", steps=3, dt=0.3) for i in range(3)}
    results = {tag: h.get_result_async() for tag, h in handles.items()}
    user.spin_until(lambda: all(r.done() for r in results.values()), "every action result")
    for tag, r in results.items():
        res = r.result()
        assert res.status == GoalStatus.STATUS_SUCCEEDED, (tag, res)
        assert res.result.ok and json.loads(res.result.value_json)["steps"] == 3, res.result
        fb = feedback.get(tag, [])
        assert any(f.state == "running" and f.host == res.result.host for f in fb), fb
        assert any(0 < f.progress <= 1 for f in fb), [f.progress for f in fb]
    # an unknown program: aborted, with the reason
    bad = send("bad", "no_such_program").get_result_async()
    user.spin_until(lambda: bad.done(), "the bad goal's result")
    assert bad.result().status == GoalStatus.STATUS_ABORTED
    assert bad.result().result.error_kind == "refused" and "no_such_program" in bad.result().result.error
    # cancelling the goal withdraws its program: the worker running it goes
    long = send("long", "sleepy", seconds=120, tag="actc")
    mark = team.marks / "actc"
    user.spin_until(lambda: mark.exists(), "the long goal to start")
    robot, pid = mark.read_text().split()
    pid = int(pid)
    cancel = long.cancel_goal_async()
    user.spin_until(lambda: cancel.done(), "the cancel answer")
    assert len(cancel.result().goals_canceling) == 1
    res = long.get_result_async()
    user.spin_until(lambda: res.done(), "the cancelled goal's result")
    assert res.result().status == GoalStatus.STATUS_CANCELED and res.result().result.error_kind == "cancelled"
    user.spin_until(lambda: _gone(pid),
                    f"the worker running the withdrawn program on {robot} to go")
    client.destroy()


def test_a_host_killed_mid_goal_loses_nothing_and_a_dead_origin_is_reported(team, user):
    """Last in this module: it kills robots of the shared team."""
    t = team

    def running() -> dict[str, str]:
        return {f["goal_id"]: f["host"] for f in user.feedback if f["state"] == "running"}

    try:  # the same through the RunProgram action, when it is built
        from ramps_interfaces.action import RunProgram
        from rclpy.action import ActionClient

        client = ActionClient(user.node, RunProgram, "/r1/ramps/run")
        user.spin_until(lambda: client.server_is_ready(), "the RunProgram action server")
    except ImportError:
        client = None
    afeedback: dict[str, list] = {}

    def send_action(name: str, **args):
        fut = client.send_goal_async(RunProgram.Goal(program="stepper", args_json=json.dumps(args),
                                                     policy="round_robin"),
                                     feedback_callback=lambda m: afeedback.setdefault(name, []).append(m.feedback))
        return user.spin_until(lambda: fut.result() if fut.done() else None, f"action goal {name} accepted")

    goals = ["k0", "k1", "k2"]
    for g in goals:  # round robin from r1: one goal on each robot
        user.send(g, "stepper", policy="round_robin", steps=8, dt=0.4)
    actions = {f"a{i}": send_action(f"a{i}", steps=8, dt=0.4) for i in range(3)} if client else {}
    user.spin_until(lambda: set(goals) <= set(running()), "all three goals running")
    user.spin_until(lambda: all(any(f.state == "running" for f in afeedback.get(a, [])) for a in actions),
                    "all three action goals running")
    hosts = {g: h for g, h in running().items() if g in goals}
    ahosts = {a: [f.host for f in afeedback[a] if f.state == "running"][0] for a in actions}
    victim = next(h for h in hosts.values() if h != "r1")
    assert not actions or victim in ahosts.values(), (ahosts, victim)  # round robin: an action goal there too
    t.kill_node(victim)
    aresults = {a: h.get_result_async() for a, h in actions.items()}
    user.spin_until(lambda: all(g in user.results for g in goals) and all(r.done() for r in aresults.values()),
                    "every goal's result")
    for a, r in aresults.items():
        res = r.result()
        assert res.status == GoalStatus.STATUS_SUCCEEDED and res.result.host != victim, (a, res)
        if ahosts[a] == victim:  # it moved: feedback said so
            states = [f.state for f in afeedback[a]]
            assert "host_failed" in states or "replaced" in states, states
    for g in goals:
        r = user.results[g]
        assert r["ok"] and r["host"] != victim, r
    moved = [g for g, h in hosts.items() if h == victim]
    for g in moved:
        states = [f["state"] for f in user.of(g)]
        assert "host_failed" in states or "replaced" in states, states
    # now the robot under the ROS face itself dies: its goals fail, clearly, and diagnostics say so
    user.send("orphan", "stepper", steps=100, dt=0.5)
    user.spin_until(lambda: any(f["state"] == "running" for f in user.of("orphan")), "the orphan running")
    aorphan = send_action("aorphan", steps=100, dt=0.5).get_result_async() if client else None
    t.kill_node("r1")
    r = user.spin_until(lambda: user.results.get("orphan"), "the orphan's result")
    assert not r["ok"] and r["error_kind"] == "lost" and "robot r1, the origin" in r["error"], r
    if aorphan is not None:
        user.spin_until(lambda: aorphan.done(), "the action orphan's result")
        res = aorphan.result()
        assert res.status == GoalStatus.STATUS_ABORTED and res.result.error_kind == "lost", res
        assert "robot r1, the origin" in res.result.error
        client.destroy()
    user.spin_until(lambda: any(s.name == "ramps: ros face" and s.level == DiagnosticStatus.ERROR
                                and "r1" in s.message for a in user.diagnostics[-2:] for s in a.status),
                    "the face's ERROR on /diagnostics")
