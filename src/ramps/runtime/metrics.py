"""Prometheus metrics of one ramps node (``ramps node --metrics ADDR:PORT``).

How this works: ``NodeMetrics`` owns its own ``CollectorRegistry`` and
prometheus_client's HTTP server (a daemon thread answering ``/metrics``).
The node's driver thread feeds it, and nothing else does, so no lock is
needed besides prometheus_client's own:

- ``on_action(action, node, now)`` for every action the core returns
  (``Note`` placed/accepted/failed/blacklisted, ``StartProgram``,
  ``Deliver``) and ``on_finished`` for every worker that ends: the
  counters and histograms;
- ``on_report(...)`` at every load report the node publishes (once a
  second): the gauges (load, run queue, teammates seen, ...).

Rules: it observes, it never decides; it only reads the core's state
(program names, when a program was submitted, report ages). Every metric
has a ``robot`` label (this node), so one Grafana query shows the team;
times are seconds, memory bytes, counters end in ``_total``.

Detection latency: a node cannot know when a teammate really failed, so
``ramps_failure_detection_seconds`` is the time between the last word from
the host (a heartbeat about the program, or its latest load report) and the
moment the origin wrote the attempt off: an upper bound on how long the
failure went unnoticed (a crash seen by TCP reset: ~0.01-1 s; a cut: the
heartbeat timeout or the session lease).
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram, Info

from ramps.core.events import Deliver, Note, StartProgram
from ramps.runtime.settings import parse_metrics_address
from ramps.version import __version__

if TYPE_CHECKING:
    import threading
    from wsgiref.simple_server import WSGIServer

#: latency buckets, seconds: from a loopback dispatch (~1 ms) to a slow recovery
LATENCY_BUCKETS = (0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.0, 3.0, 5.0, 10.0, 30.0)
#: program run times, seconds
DURATION_BUCKETS = (0.01, 0.05, 0.1, 0.25, 0.5, 1, 2.5, 5, 10, 25, 50, 100, 250, 500, 1000)
#: (program, attempt) offers and failures remembered for latency figures; older are forgotten
MAX_PENDING = 10_000
#: why an origin writes an attempt off (ramps.core.program); their series exist from the start at 0,
#: since Prometheus' rate() and increase() cannot see the first event of a series born at 1
FAILURE_REASONS = ("host_lost", "heartbeat_timeout", "connect_timeout", "worker_lost")


def _reason(detail: str) -> str:
    """A failure's reason as a label with few values: heartbeat_timeout,
    host_lost, connect_timeout, worker_lost, ..."""
    word = detail.split(":", 1)[0].strip().replace(" ", "_")
    return word[:40] or "unknown"


class NodeMetrics:
    def __init__(self, robot: str, team: str, *, cores: int = 0, speed: float = 0.0, policy: str = "") -> None:
        self.robot = robot
        self.registry = reg = CollectorRegistry(auto_describe=True)
        self._server: WSGIServer | None = None
        self._thread: threading.Thread | None = None
        self.address: tuple[str, int] | None = None
        r = ("robot",)
        Info("ramps_node", "this ramps node", r, registry=reg).labels(robot).info(
            {"team": team, "policy": policy, "version": __version__})
        self.placed = Counter("ramps_programs_placed", "programs this origin offered to a host (attempts)",
                              r + ("host", "program"), registry=reg)
        self.replaced = Counter("ramps_programs_replaced", "attempts after the first: programs this origin "
                                "placed again after a failure, rejection or lost worker", r + ("program",),
                                registry=reg)
        self.accepted = Counter("ramps_programs_accepted", "offers a host accepted", r + ("host", "program"),
                                registry=reg)
        self.rejected = Counter("ramps_programs_rejected", "offers a host turned down", r + ("host",), registry=reg)
        self.failed = Counter("ramps_program_attempts_failed", "attempts written off: the host failed, went "
                              "silent or lost the worker", r + ("host", "program", "reason"), registry=reg)
        self.delivered = Counter("ramps_programs_delivered", "programs whose one outcome was delivered to the "
                                 "application", r + ("program", "outcome"), registry=reg)
        self.blacklisted = Counter("ramps_blacklistings", "teammates this robot wrote off", r + ("host",),
                                   registry=reg)
        self.misdeclared = Counter("ramps_calls_misdeclared", "completed calls that took more than 4x or less "
                                   "than a quarter of the work their program declares", r + ("program",),
                                   registry=reg)
        self.deadline_misses = Counter("ramps_deadline_misses", "programs with a deadline delivered after it, "
                                       "or refused at once as unmeetable (on_miss=fail)", r + ("program",),
                                       registry=reg)
        self.run = Counter("ramps_programs_run", "programs this robot's executor started (for any origin)",
                           r + ("program", "origin"), registry=reg)
        self.finished = Counter("ramps_programs_finished", "programs this robot's executor finished",
                                r + ("program", "outcome"), registry=reg)
        self.dispatch = Histogram("ramps_dispatch_seconds", "offer to acceptance of one attempt (origin side)",
                                  r, buckets=LATENCY_BUCKETS, registry=reg)
        self.detection = Histogram("ramps_failure_detection_seconds", "last word from a host to writing its "
                                   "attempt off: an upper bound on how long a failure went unnoticed",
                                   r + ("reason",), buckets=LATENCY_BUCKETS, registry=reg)
        self.recovery = Histogram("ramps_recovery_seconds", "attempt written off to the program accepted "
                                  "elsewhere", r, buckets=LATENCY_BUCKETS, registry=reg)
        self.duration = Histogram("ramps_program_duration_seconds", "submission to delivery at the origin",
                                  r + ("program",), buckets=DURATION_BUCKETS, registry=reg)
        g = {}
        for name, doc in (("ramps_cores", "cores this robot offers to programs"),
                          ("ramps_speed_work_units_per_second", "work units per second per core"),
                          ("ramps_cpu_busy_cores", "CPU in use, in cores, averaged over the load window"),
                          ("ramps_run_queue", "runnable tasks (programs and other software), averaged"),
                          ("ramps_load_average_1m", "the host's 1-minute load average"),
                          ("ramps_memory_free_bytes", "memory available"),
                          ("ramps_programs_running", "programs running in this robot's executor"),
                          ("ramps_programs_in_flight", "programs of this origin not yet delivered"),
                          ("ramps_teammates_seen", "teammates this robot could place a program on now"),
                          ("ramps_blacklisted_teammates", "teammates on this robot's blacklist now"),
                          ("ramps_one_way_teammates", "teammates heard one way only now (a split Zenoh "
                           "session: restart either node)")):
            g[name] = Gauge(name, doc, r, registry=reg).labels(robot)
        self.g = g
        g["ramps_cores"].set(cores)
        g["ramps_speed_work_units_per_second"].set(speed)
        self.dropped = Counter("ramps_messages_dropped", "malformed or excess messages dropped", r,
                               registry=reg).labels(robot)
        self.reports = Counter("ramps_load_reports_received", "teammates' load reports received", r,
                               registry=reg).labels(robot)
        for reason in FAILURE_REASONS:
            self.detection.labels(robot, reason)
        self.recovery.labels(robot)
        self.dispatch.labels(robot)
        self._known: set[tuple[str, str]] = set()  # (host, program) whose series exist
        self._dropped_seen = 0
        self._reports_seen = 0
        self._offered: dict[tuple[str, int], float] = {}  # (pid, attempt) -> when placed
        self._written_off: dict[str, float] = {}  # pid -> when its last attempt was written off
        self._running: dict[tuple[str, int], str] = {}  # executor: (pid, attempt) -> program

    # ------------------------------------------------------------ serving
    def serve(self, address: str) -> tuple[str, int]:
        """Serve ``/metrics`` on ``address`` (``ADDR:PORT``, as the setting
        ``metrics``: ``ramps.runtime.settings.parse_metrics_address``); returns
        the real (addr, port). Raises OSError when the port is taken."""
        from prometheus_client import start_http_server

        host, port = parse_metrics_address(address)
        server, self._thread = start_http_server(port, addr=host, registry=self.registry)
        self._server = server
        self.address = (host, server.server_port)
        return self.address

    def close(self) -> None:
        if self._server is not None:
            self._server.shutdown()
            self._server.server_close()
            self._server = None

    # ------------------------------------------------------------ feeding
    def on_action(self, a: Any, node: Any, now: float | None = None) -> None:
        """One action of the core (driver thread). ``node`` is the core
        ``Node``, read for program names and ages only."""
        now = time.monotonic() if now is None else now
        me = self.robot
        if isinstance(a, Note):
            what = a.what
            if what == "placed":
                prog = _program(node, a.program_id)
                self._born(a.robot, prog)
                self.placed.labels(me, a.robot, prog).inc()
                if a.attempt > 1:
                    self.replaced.labels(me, prog).inc()
                self._remember(self._offered, (a.program_id, a.attempt), now)
            elif what == "accepted":
                self.accepted.labels(me, a.robot, _program(node, a.program_id)).inc()
                t = self._offered.pop((a.program_id, a.attempt), None)
                if t is not None:
                    self.dispatch.labels(me).observe(max(0.0, now - t))
                t = self._written_off.pop(a.program_id, None)
                if t is not None:
                    self.recovery.labels(me).observe(max(0.0, now - t))
            elif what == "rejected":
                self.rejected.labels(me, a.robot).inc()
                self._offered.pop((a.program_id, a.attempt), None)
            elif what == "failed":
                reason = _reason(a.detail)
                self.failed.labels(me, a.robot, _program(node, a.program_id), reason).inc()
                self._offered.pop((a.program_id, a.attempt), None)
                silent = _silence(node, a.program_id, a.robot, now)
                if silent is not None:
                    self.detection.labels(me, reason).observe(silent)
                self._remember(self._written_off, a.program_id, now)
            elif what == "blacklisted":
                self.blacklisted.labels(me, a.robot).inc()
            elif what == "misdeclared":
                self.misdeclared.labels(me, _program(node, a.program_id)).inc()
            elif what == "deadline_missed":
                self.deadline_misses.labels(me, _program(node, a.program_id)).inc()
            elif what in ("one_way", "two_way"):
                self.g["ramps_one_way_teammates"].inc(1 if what == "one_way" else -1)
        elif isinstance(a, StartProgram):
            self.run.labels(me, a.program, a.origin).inc()
            self._remember(self._running, (a.program_id, a.attempt), a.program)
        elif isinstance(a, Deliver):
            prog = _program(node, a.program_id)
            self.delivered.labels(me, prog, "ok" if a.ok else (a.error_kind or "error")).inc()
            ap = getattr(getattr(node, "origin", None), "programs", {}).get(a.program_id)
            if ap is not None:
                self.duration.labels(me, prog).observe(max(0.0, now - ap.submitted_at))
            self._written_off.pop(a.program_id, None)

    def on_finished(self, f: Any) -> None:
        """A worker of this robot's executor ended (``ProgramFinished``, driver thread)."""
        prog = self._running.pop((f.program_id, f.attempt), None)
        if prog is not None:
            self.finished.labels(self.robot, prog, "ok" if f.ok else ("lost" if f.retryable else "error")).inc()

    def on_report(self, *, cpu_busy: float, runnable: float, load_avg: float, mem_free: int, running: int,
                  in_flight: int, sees: int, blacklisted: int, dropped: int, reports_received: int) -> None:
        """The node's own load report, as published (driver thread)."""
        g = self.g
        g["ramps_cpu_busy_cores"].set(cpu_busy)
        g["ramps_run_queue"].set(runnable)
        g["ramps_load_average_1m"].set(load_avg)
        g["ramps_memory_free_bytes"].set(mem_free)
        g["ramps_programs_running"].set(running)
        g["ramps_programs_in_flight"].set(in_flight)
        g["ramps_teammates_seen"].set(sees)
        g["ramps_blacklisted_teammates"].set(blacklisted)
        if dropped > self._dropped_seen:
            self.dropped.inc(dropped - self._dropped_seen)
        self._dropped_seen = max(self._dropped_seen, dropped)
        if reports_received > self._reports_seen:
            self.reports.inc(reports_received - self._reports_seen)
        self._reports_seen = max(self._reports_seen, reports_received)

    def _born(self, host: str, prog: str) -> None:
        """Create at 0 the series a placement on ``host`` may move later, so
        that their first increment shows in rate() and increase()."""
        if (host, prog) in self._known or len(self._known) > MAX_PENDING:
            return
        self._known.add((host, prog))
        me = self.robot
        for reason in FAILURE_REASONS:
            self.failed.labels(me, host, prog, reason)
        self.accepted.labels(me, host, prog)
        self.rejected.labels(me, host)
        self.blacklisted.labels(me, host)
        self.replaced.labels(me, prog)
        self.delivered.labels(me, prog, "ok")
        self.duration.labels(me, prog)

    @staticmethod
    def _remember(table: dict[Any, Any], key: Any, value: Any) -> None:
        table[key] = value
        if len(table) > MAX_PENDING:
            table.pop(next(iter(table)))


def _program(node: Any, program_id: str) -> str:
    ap = getattr(getattr(node, "origin", None), "programs", {}).get(program_id)
    return ap.submit.program if ap is not None else "unknown"


def _silence(node: Any, program_id: str, host: str, now: float) -> float | None:
    """Seconds since the last word from ``host``: a heartbeat about the
    program (unless the origin already re-placed it this instant) or its
    latest load report, whichever is newer."""
    ages = []
    ap = getattr(getattr(node, "origin", None), "programs", {}).get(program_id)
    if ap is not None and ap.last_heard < now:
        ages.append(now - ap.last_heard)
    view = getattr(node, "view", None)
    age = view.report_age(host, now) if view is not None and host else None
    if age is not None:
        ages.append(age)
    return max(0.0, min(ages)) if ages else None


__all__ = ["NodeMetrics", "LATENCY_BUCKETS"]
