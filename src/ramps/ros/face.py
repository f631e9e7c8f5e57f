"""``ramps ros``: a robot's ramps team as ROS 2 topics (needs the ``ros`` extra).

How this works: ``RosFace`` is an rclpy node and a ramps client
(``ramps.connect``) of its robot's ramps node, the origin of every program it
submits. ROS clients send goals as JSON on a topic; each goal becomes one
``team.submit``; the program's ``ProgramFuture`` updates (placed, running,
re-placed, progress) become feedback, its outcome becomes the result, and
cancelling the goal cancels the future, which withdraws the program from the
team. The team's load reports are published as ``diagnostic_msgs``
(``ramps.ros.diagnostics``).

Two ways in, on standard types and on ramps' own action:

- ``~/run``, the ROS 2 action ``ramps_interfaces/action/RunProgram``
  (``interfaces/RunProgram.action``): goal = program and ``args_json``,
  feedback = state, host, attempt, progress (-1 before any; news of it comes
  with state ``running``), result = ok,
  ``value_json`` or error and error_kind, host, attempts; cancelling the goal
  withdraws the program. The type is built into the environment by
  ``ramps ros --build-interfaces`` (``ramps.ros.build``: rosidl from the
  ROS wheels, cmake and a compiler); the action is served when it imports.
- topics that need nothing built, for any ROS tool: goals, cancels,
  feedback and results as JSON in ``std_msgs/String``, goal states on
  ``action_msgs/GoalStatusArray`` with the standard codes.

Names (relative to the node, ``/<robot>/ramps/...`` by default):

- ``~/goal`` (std_msgs/String, in): ``{"goal_id": "g1", "program": "route_plan",
  "args": {"seed": 3}, "timeout": 60}``; ``goal_id`` optional (one is made),
  ``timeout`` optional (seconds, then the program is withdrawn), ``policy``
  optional (a placement policy for this goal: ramps, round_robin, ...)
- ``~/cancel`` (std_msgs/String, in): a goal id
- ``~/feedback`` (std_msgs/String, out): ``{"goal_id", "program", "state",
  "host", "attempt", "progress", "detail"}``; state: accepted, placed,
  running, replaced, host_failed (where the program stands: a new progress
  fraction comes as another ``running`` feedback, ``progress`` updated)
- ``~/result`` (std_msgs/String, out, latched for 100): ``{"goal_id",
  "program", "ok", "value" | "error" and "error_kind", "host", "attempts"}``;
  error_kind: program, refused, bad_arguments, bad_goal, cancelled, lost,
  timeout
- ``~/status`` (action_msgs/GoalStatusArray, out, latched): every goal of
  the last minute; goal ids are ``uuid5(NAMESPACE_URL, "ramps:" + goal_id)``
- ``/diagnostics`` (diagnostic_msgs/DiagnosticArray, out): one status per
  robot ("ramps: r2": cores, speed, CPU busy, run queue, programs, ...), and
  one for this face; every ``diagnostics_period`` seconds

Parameters: team, robot (the origin node; default any), connect (string array of Zenoh endpoints),
multicast, secure, credentials, diagnostics_period (s), goal_timeout (s, 0 = none), connect_timeout
(s), origin_grace (s goals wait for their node's restart, then fail as ``lost``), battery_file and
battery_topic (the robot's battery into its node's, ``ramps.ros.battery``). Team, connect, multicast,
secure and credentials not given as parameters come from the environment and config file
(``RAMPS_TEAM``, ...), as for ``ramps.connect``.

Rules: future callbacks (Zenoh threads) only enqueue and trigger a guard
condition; the executor's thread drains the queue and publishes, so every
ROS call happens on that one thread. A bad goal gets an error result (and a log line), never an exception.
"""

from __future__ import annotations

import base64
import json
import queue
import re
import time
import uuid
from typing import Any

import rclpy
import rclpy.executors
import rclpy.task
from action_msgs.msg import GoalInfo, GoalStatus, GoalStatusArray
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from std_msgs.msg import String
from unique_identifier_msgs.msg import UUID

from ramps.ros.battery import bridge_battery
from ramps.ros.diagnostics import robot_status
from ramps.runtime.client import ORIGIN_GONE_GRACE
from ramps.runtime.registry import MAX_ARGS_BYTES

try:  # the RunProgram action, once built (ramps ros --build-interfaces)
    from ramps_interfaces.action import RunProgram
except ImportError:
    RunProgram = None

#: seconds a finished goal stays in the status array
KEEP_FINISHED = 60.0
#: longest goal message accepted, bytes: ramps' own argument limit and room
#: for the goal's other fields
MAX_GOAL_BYTES = MAX_ARGS_BYTES + 4096
#: seconds between two looks at the goals without news (expiry, status)
HOUSEKEEPING_PERIOD = 0.5

RELIABLE = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST)
LATCHED = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
STATUS_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, history=HistoryPolicy.KEEP_LAST,
                        durability=DurabilityPolicy.TRANSIENT_LOCAL)

_FUTURE_STATES = {"submitted": "accepted", "placed": "placed", "running": "running", "replaced": "replaced",
                  "host_failed": "host_failed"}


def ros_name(text: str) -> str:
    """A robot name as a ROS namespace token (letters, digits, underscores)."""
    out = re.sub(r"[^A-Za-z0-9_]", "_", text) or "ramps"
    return out if not out[0].isdigit() else "r" + out


def goal_uuid(goal_id: str) -> bytes:
    return uuid.uuid5(uuid.NAMESPACE_URL, "ramps:" + goal_id).bytes


def _jsonable(value: Any) -> Any:
    if isinstance(value, (bytes, bytearray, memoryview)):
        return {"base64": base64.b64encode(bytes(value)).decode()}
    return str(value)


class _Goal:
    __slots__ = ("goal_id", "program", "uuid", "stamp", "status", "fut", "done_at", "action")

    def __init__(self, goal_id: str, program: str, stamp) -> None:
        self.goal_id = goal_id
        self.program = program
        self.uuid = goal_uuid(goal_id)
        self.stamp = stamp
        self.status = GoalStatus.STATUS_ACCEPTED
        self.fut = None
        self.done_at: float | None = None
        #: (goal handle, rclpy future of the outcome) for a goal of the RunProgram action
        self.action = None


class RosFace(Node):
    def __init__(self, *, namespace: str = "", overrides: dict[str, Any] | None = None, team=None) -> None:
        super().__init__("ramps", namespace=namespace,
                         parameter_overrides=[Parameter(k, value=v) for k, v in (overrides or {}).items()])
        p = self._declare()
        self.params = p
        if team is None:
            import ramps

            # unset parameters are None: RAMPS_TEAM, RAMPS_MULTICAST, RAMPS_CONFIG ... decide, as for any client
            team = ramps.connect(team=p["team"] or None, robot=p["robot"] or None, connect=p["connect"] or None,
                                 multicast=p["multicast"], secure=p["secure"], credentials=p["credentials"] or None,
                                 timeout=p["connect_timeout"], origin_grace=p["origin_grace"])
        self.team = team
        self.origin = team.robot
        self._events: queue.SimpleQueue = queue.SimpleQueue()
        self._goals: dict[str, _Goal] = {}
        self._ids = 0
        self._status_dirty = True
        self.bad_goals = 0
        self.pub_feedback = self.create_publisher(String, "~/feedback", RELIABLE)
        self.pub_result = self.create_publisher(String, "~/result", LATCHED)
        self.pub_status = self.create_publisher(GoalStatusArray, "~/status", STATUS_QOS)
        self.pub_diag = self.create_publisher(DiagnosticArray, "/diagnostics", RELIABLE)
        self.create_subscription(String, "~/goal", lambda m: self._handle("goal", m.data), RELIABLE)
        self.create_subscription(String, "~/cancel", lambda m: self._handle("cancel", m.data), RELIABLE)
        self.battery = bridge_battery(self)  # sensor_msgs/BatteryState into the node's battery file, if asked
        # future callbacks (Zenoh threads) enqueue and wake the executor through this
        self._wake = self.create_guard_condition(self._pump)
        self.create_timer(HOUSEKEEPING_PERIOD, self._pump)
        self.create_timer(p["diagnostics_period"], self._publish_diagnostics)
        self.action_server = None
        if RunProgram is not None:
            from rclpy.action import ActionServer, CancelResponse

            self._cancel_ok = CancelResponse.ACCEPT
            self.action_server = ActionServer(self, RunProgram, "~/run", execute_callback=self._execute,
                                              cancel_callback=self._cancel_action)
        self.get_logger().info(
            f"ramps ROS face of team {team.team!r} via robot {self.origin}: goals on "
            f"{self.resolve_topic_name('~/goal')}, results on {self.resolve_topic_name('~/result')}, "
            f"load on /diagnostics every {p['diagnostics_period']:g} s"
            + (f"; action ramps_interfaces/action/RunProgram on {self.resolve_topic_name('~/run')}"
               if self.action_server else "; no RunProgram action (ramps ros --build-interfaces builds it)"))

    def _declare(self) -> dict[str, Any]:
        # ramps' own settings have no default here (a typed parameter without a value reads None), so
        # what is not given falls to the environment and config file in ramps.connect; the face's own
        # settings have theirs
        defaults = {"team": Parameter.Type.STRING, "robot": Parameter.Type.STRING, "multicast": Parameter.Type.BOOL,
                    "secure": Parameter.Type.BOOL, "credentials": Parameter.Type.STRING,
                    "connect": Parameter.Type.STRING_ARRAY, "diagnostics_period": 1.0, "goal_timeout": 0.0,
                    "connect_timeout": 10.0, "origin_grace": ORIGIN_GONE_GRACE}
        wants = {Parameter.Type.STRING: "a string", Parameter.Type.BOOL: "true or false",
                 Parameter.Type.STRING_ARRAY: "a list of strings"}
        out: dict[str, Any] = {}
        for k, v in defaults.items():
            number = isinstance(v, float)  # seconds: 2 is as good as 2.0
            try:
                out[k] = self.declare_parameter(
                    k, v, ParameterDescriptor(dynamic_typing=True) if number else ParameterDescriptor()).value
                if number:
                    out[k] = float(out[k])
            except Exception as exc:  # rclpy's InvalidParameterTypeException, float("x"): say which and what
                want = "a number" if isinstance(v, float) else wants[v]
                raise ValueError(f"ROS parameter {k!r} must be {want} ({type(exc).__name__}: {exc})") from None
        out["connect"] = list(out["connect"] or [])
        if not out["diagnostics_period"] > 0:
            raise ValueError(f"diagnostics_period must be > 0 s, got {out['diagnostics_period']}")
        if not out["origin_grace"] >= 0:
            raise ValueError(f"origin_grace must be >= 0 s, got {out['origin_grace']}")
        return out

    # ------------------------------------------------------------ the one thread that talks to ROS
    def _enqueue(self, kind: str, data) -> None:
        """From any thread: hand a future's news to the executor's thread."""
        self._events.put((kind, data))
        self._wake.trigger()

    def _future_changed(self, goal_id: str, f) -> None:
        """A future's update callback (a Zenoh thread): snapshot it now, as
        later updates may change it before the executor's thread looks."""
        if f.done():
            self._enqueue("done", goal_id)
        else:
            self._enqueue("update", (goal_id, f.state, f.host, f.attempts, f.progress, f.progress_detail))

    def _pump(self) -> None:
        for _ in range(10_000):
            try:
                kind, data = self._events.get_nowait()
            except queue.Empty:
                break
            self._handle(kind, data)
        self._expire()
        if self._status_dirty:
            self._publish_status()

    def _handle(self, kind: str, data) -> None:
        try:
            if kind == "goal":
                self._on_goal(data)
            elif kind == "cancel":
                self._on_cancel(data.strip())
            elif kind == "update":
                self._on_update(data)
            elif kind == "done":
                self._on_done(data)
        except Exception as exc:  # a bug here must not stop the face: say so
            self.get_logger().error(f"ramps ROS face: error handling {kind}: {type(exc).__name__}: {exc}")
        if self._status_dirty and kind in ("goal", "cancel"):
            self._publish_status()

    def _on_goal(self, text: str) -> None:
        goal_id = ""
        try:
            if len(text) > MAX_GOAL_BYTES:
                raise ValueError(f"goal is {len(text)} bytes; the limit is {MAX_GOAL_BYTES}")
            goal = json.loads(text)
            if not isinstance(goal, dict):
                raise ValueError("a goal is a JSON object: {\"program\": NAME, \"args\": {...}}")
            goal_id = str(goal.get("goal_id") or "")
            program = goal.get("program")
            args = goal.get("args", {})
            timeout = goal.get("timeout", self.params["goal_timeout"]) or None
            policy = goal.get("policy", "")
            if not isinstance(program, str) or not program:
                raise ValueError("goal needs \"program\": the name of a registered program")
            if not isinstance(args, dict):
                raise ValueError("\"args\" must be a JSON object of keyword arguments")
            if timeout is not None and not (isinstance(timeout, (int, float)) and timeout > 0):
                raise ValueError(f"\"timeout\" must be a positive number of seconds, got {timeout!r}")
            if not isinstance(policy, str):
                raise ValueError(f"\"policy\" must be a placement policy's name, got {policy!r}")
        except ValueError as exc:
            self.bad_goals += 1
            self.get_logger().warning(f"bad goal refused: {exc}")
            self._result({"goal_id": goal_id, "program": "", "ok": False, "error": f"bad goal: {exc}",
                          "error_kind": "bad_goal", "host": "", "attempts": 0})
            return
        if not goal_id:
            self._ids += 1
            goal_id = f"{self.origin}-{int(time.time())}-{self._ids}"
        if goal_id in self._goals:
            self.get_logger().warning(f"goal {goal_id!r} was sent already; ignored")
            return
        self._start(goal_id, program, args, timeout, policy)

    def _start(self, goal_id: str, program: str, args: dict, timeout, policy: str, action=None) -> "_Goal":
        g = self._goals[goal_id] = _Goal(goal_id, program, self.get_clock().now().to_msg())
        g.action = action
        self._status_dirty = action is None
        try:
            fut = self.team.options(timeout=timeout, policy=policy).submit(program, **args)
        except Exception as exc:  # unknown program, arguments that cannot be sent, a closed team
            self._finish(g, {"ok": False, "error": str(exc), "error_kind": _kind(exc), "host": "", "attempts": 0})
            return g
        g.fut = fut
        g.status = GoalStatus.STATUS_EXECUTING
        self._feedback(g, "accepted", "", 0, None, "")
        fut.add_update_callback(lambda f, gid=goal_id: self._future_changed(gid, f))
        return g

    # ------------------------------------------------------------ the RunProgram action
    async def _execute(self, goal_handle):
        """A RunProgram goal: submit, relay feedback, return the outcome."""
        req = goal_handle.request
        goal_id = "action-" + bytes(goal_handle.goal_id.uuid).hex()
        done = rclpy.task.Future()
        try:
            args = json.loads(req.args_json or "{}")
            if not isinstance(args, dict):
                raise ValueError("args_json must be a JSON object of keyword arguments")
            if not req.program:
                raise ValueError("program is empty: name a registered program")
            if not (req.timeout >= 0):
                raise ValueError(f"timeout must be >= 0 seconds, got {req.timeout}")
        except ValueError as exc:
            self.bad_goals += 1
            goal_handle.abort()
            return RunProgram.Result(ok=False, error=f"bad goal: {exc}", error_kind="bad_goal")
        self._start(goal_id, req.program, args, req.timeout or self.params["goal_timeout"] or None, req.policy,
                    action=(goal_handle, done))
        out = await done
        kind = out.get("error_kind", "")
        if out["ok"]:
            goal_handle.succeed()
        elif kind == "cancelled" and goal_handle.is_cancel_requested:
            goal_handle.canceled()
        else:
            goal_handle.abort()
        return RunProgram.Result(ok=out["ok"], value_json=json.dumps(out.get("value"), default=_jsonable),
                                 error=out.get("error", ""), error_kind=kind, host=out.get("host", ""),
                                 attempts=out.get("attempts", 0))

    def _cancel_action(self, goal_handle):
        g = self._goals.get("action-" + bytes(goal_handle.goal_id.uuid).hex())
        if g is not None and g.fut is not None and g.done_at is None:
            g.fut.cancel()  # withdraws the program; its outcome ends the goal as canceled
        return self._cancel_ok

    def _on_cancel(self, goal_id: str) -> None:
        g = self._goals.get(goal_id)
        if g is None or g.done_at is not None:
            self.get_logger().info(f"cancel of unknown or finished goal {goal_id!r} ignored")
            return
        g.status = GoalStatus.STATUS_CANCELING
        self._status_dirty = True
        if g.fut is not None:
            g.fut.cancel()  # withdraws the program from the team; the done callback reports it

    def _on_update(self, snapshot: tuple) -> None:
        goal_id, state, host, attempts, progress, detail = snapshot
        g = self._goals.get(goal_id)
        if g is None or g.fut is None or g.done_at is not None:
            return
        self._feedback(g, _FUTURE_STATES.get(state, state), host, attempts, progress, detail)

    def _on_done(self, goal_id: str) -> None:
        g = self._goals.get(goal_id)
        if g is None or g.fut is None or g.done_at is not None:
            return
        f = g.fut
        if f.cancelled():
            out = {"ok": False, "error": "cancelled: the program was withdrawn from the team", "error_kind": "cancelled"}
        else:
            exc = f.exception()
            if exc is None:
                out = {"ok": True, "value": f.result()}
            else:
                out = {"ok": False, "error": f"{type(exc).__name__}: {exc}", "error_kind": _kind(exc)}
        out.update(host=f.host, attempts=f.attempts)
        self._finish(g, out)

    def _finish(self, g: _Goal, out: dict[str, Any]) -> None:
        g.done_at = time.monotonic()
        kind = out.get("error_kind")
        g.status = (GoalStatus.STATUS_SUCCEEDED if out["ok"] else
                    GoalStatus.STATUS_CANCELED if kind == "cancelled" else GoalStatus.STATUS_ABORTED)
        if g.action is not None:  # the action server reports it (result, status)
            g.action[1].set_result(out)
            return
        self._status_dirty = True
        self._result({"goal_id": g.goal_id, "program": g.program, **out})

    # ------------------------------------------------------------ publishing
    def _feedback(self, g: _Goal, state: str, host: str, attempt: int, progress, detail: str) -> None:
        if g.action is not None:
            g.action[0].publish_feedback(RunProgram.Feedback(
                state=state, host=host, attempt=attempt, progress=-1.0 if progress is None else float(progress),
                detail=detail))
            return
        self.pub_feedback.publish(String(data=json.dumps({
            "goal_id": g.goal_id, "program": g.program, "state": state, "host": host, "attempt": attempt,
            "progress": progress, "detail": detail})))

    def _result(self, out: dict[str, Any]) -> None:
        self.pub_result.publish(String(data=json.dumps(out, default=_jsonable)))

    def _expire(self) -> None:
        horizon = time.monotonic() - KEEP_FINISHED
        for gid in [gid for gid, g in self._goals.items() if g.done_at is not None and g.done_at < horizon]:
            del self._goals[gid]
            self._status_dirty = True

    def _publish_status(self) -> None:
        self._status_dirty = False
        arr = GoalStatusArray()
        for g in self._goals.values():
            if g.action is not None:
                continue  # the action server's own status topic has it
            arr.status_list.append(GoalStatus(goal_info=GoalInfo(goal_id=UUID(uuid=list(g.uuid)), stamp=g.stamp),
                                              status=g.status))
        self.pub_status.publish(arr)

    def _publish_diagnostics(self) -> None:
        st = self.team.status()
        arr = DiagnosticArray()
        arr.header.stamp = self.get_clock().now().to_msg()
        period = self.params["diagnostics_period"]
        robots = [r for r in st.robots]
        team_size = sum(1 for r in robots if r.alive)
        origin_alive = any(r.robot == self.origin and r.alive for r in robots)
        for r in robots:
            arr.status.append(robot_status(r, team_size, stale_after=max(5.0, 3 * period)))
        running = sum(1 for g in self._goals.values() if g.done_at is None)
        face = DiagnosticStatus(name="ramps: ros face", hardware_id=self.origin)
        if origin_alive:
            face.level, face.message = DiagnosticStatus.OK, f"goals go to robot {self.origin}; {running} running"
        else:
            face.level = DiagnosticStatus.ERROR
            face.message = (f"robot {self.origin} (this face's ramps node) is gone: goals cannot run "
                            f"({running} lost with it)")
        face.values = [KeyValue(key="origin", value=self.origin), KeyValue(key="team", value=st.team),
                       KeyValue(key="goals running", value=str(running)),
                       KeyValue(key="bad goals", value=str(self.bad_goals))]
        arr.status.append(face)
        self.pub_diag.publish(arr)

    def close(self) -> None:
        """Withdraw running goals (their results say so), leave the team."""
        for g in self._goals.values():
            if g.done_at is None and g.fut is not None:
                g.fut.cancel()
        try:
            self.team.close()
        finally:
            self.destroy_node()


def _kind(exc: BaseException) -> str:
    from ramps.errors import BadArguments, ProgramFailed, ProgramLost, ProgramNotFound, ProgramRefused

    for cls, kind in ((ProgramFailed, "program"), (ProgramRefused, "refused"), (ProgramNotFound, "refused"),
                      (BadArguments, "bad_arguments"), (ProgramLost, "lost"), (TimeoutError, "timeout")):
        if isinstance(exc, cls):
            return kind
    return "error"


def run(*, namespace: str, overrides: dict[str, Any], ros_args: list[str] | None = None) -> None:
    """``ramps ros``: run the face until Ctrl-C / SIGTERM."""
    import signal

    rclpy.init(args=["ramps-ros", *(ros_args or [])])
    face = None
    try:
        face = RosFace(namespace=namespace, overrides=overrides)
        signal.signal(signal.SIGTERM, lambda *_: rclpy.try_shutdown())
        try:
            rclpy.spin(face)
        except (KeyboardInterrupt, rclpy.executors.ExternalShutdownException):
            pass
    finally:
        if face is not None:
            face.close()
        rclpy.try_shutdown()
