"""``ramps node``: one robot's load publisher, load server and program executor.

How this works: a ``NodeRuntime`` owns one ``ramps.core.node.Node`` and is
its driver. Zenoh callbacks, the worker pool and the load sampler only put
items on one queue; a single driver thread takes them, stamps the monotonic
time, calls the core and applies the actions it returns (publish a message,
start or kill a worker, send an outcome to a client). No placement, failure
or recovery decision is made here.

Applications (clients) submit to their robot's node with ``SubmitProgram``;
the node's core is the origin of the autonomous program and the node sends
the one ``ProgramOutcome`` back to the client's key. The node checks the
program name and the arguments against the program's signature and
annotated types before it places anything, so a bad call fails at the
caller.

Shutdown (SIGINT/SIGTERM, ``stop()``): the executor hands every running
program back to its origin (a retryable result, so the origin places it
elsewhere at once), programs this node is origin of are cancelled and their
clients told, then the liveliness token, subscribers and transport close.

The driver reaches the team only through ``ramps.runtime.transport`` (a
Zenoh session in production, ``ramps.testing.memory`` in tests) and reads
time only from its injected clock. This module is its lifecycle and loop.
The rest are parts it holds, each with its own state and given the other
parts it uses; one that reads the driver itself sees it through a protocol
of its own (``InboundDriver``, ``OutboundDriver``, ``ClientsDriver``,
``ReportsDriver``), which mypy checks ``NodeRuntime`` against. The parts:
what it does with each input (``node_inbound.Inbound``), the core's actions
applied (``node_outbound.Outbound``, given the parts that stand on their
own as one ``node_parts.NodeParts``), its clients' requests and outcomes
(``node_clients.ClientAnswers``), its load reports
(``node_reports.LoadReports``), its publishing (``node_outbox.Outbox``),
what it makes of the bytes it receives (``node_intake.WireIntake``), the
core's clock with stalls taken out and the teammates lost during one
(``node_awake``), the robot's cores and speed (``node_robot.RobotMeasure``),
its subscriptions and tokens on the transport (``node_team.Membership``),
other nodes under its robot name (``node_name.SameName``), the team's
revocation list (``node_revoked.Revoked``) and its trace file
(``node_trace.NodeTrace``).
"""

from __future__ import annotations

import gc
import logging
import os
import queue
import random
import threading
from typing import TYPE_CHECKING, Any, Callable

from ramps.core.cost import nice_weight
from ramps.core.events import Action, Note
from ramps.core.identity import new_incarnation
from ramps.core.node import Node
from ramps.core.wirepeek import can_wait
from ramps.errors import ConfigError, NotAdmitted, TransportError
from ramps.runtime.accelerators import AcceleratorProbe
from ramps.runtime.accelerators import resolve as resolve_accelerators
from ramps.runtime.heap import HeapTrimmer, return_freed_memory
from ramps.runtime.niceness import prioritize, worker_increment
from ramps.runtime.measure import LoadSampler
from ramps.runtime.registry import Registry, default_registry, node_registry
from ramps.runtime.settings import NodeSettings
from ramps.runtime.store import OriginStore
from ramps.runtime.transport import REAL_CLOCK, Clock, Transport, ZenohTransport
from ramps.runtime.workers import WorkerPool
from ramps.runtime.node_clients import OUTCOME_HOLD, ClientAnswers, close_record
from ramps.runtime.node_inbound import LONELY_AFTER, STALL_GRACE, Inbound
from ramps.runtime.node_intake import DROP_LOG_PERIOD, WireIntake
from ramps.runtime.node_outbound import Outbound
from ramps.runtime.node_parts import NodeParts
from ramps.runtime.node_awake import AwakeClock, HeldLosses
from ramps.runtime.node_outbox import Outbox
from ramps.runtime.node_name import SameName
from ramps.runtime.node_reports import PROMPT_HOLD, LoadReports
from ramps.runtime.node_revoked import Revoked
from ramps.runtime.node_robot import RobotMeasure, core_config
from ramps.runtime.node_team import Membership, join_checks
from ramps.runtime.node_trace import NodeTrace
from ramps.runtime.node_seams import SamplerLike, WorkerPoolLike

if TYPE_CHECKING:
    from ramps.runtime.credentials import Credentials
    from ramps.runtime.metrics import NodeMetrics
    from ramps.runtime.revocation import RevocationList

log = logging.getLogger("ramps.node")
#: bytes of received messages waiting for the driver before new ones are dropped
MAX_BACKLOG_BYTES = 64 * 1024 * 1024
#: queued items handled before the timers fire (the rest after them)
MAX_ITEMS_PER_ROUND = 10_000
#: seconds of queued items one round handles before this robot's own duties
#: that are due (its load report, its programs' heartbeats) go out; the
#: origin's timeouts wait until the queue is drained, as it may hold the
#: heartbeats they wait for (issue 23: a saturated robot's node)
ROUND_SECONDS = 0.1


class NodeRuntime:
    """One robot's node. ``transport`` (default: a Zenoh session opened
    from ``settings`` at ``start()``), ``clock`` (default: the real one),
    ``worker_pool`` and ``load_sampler`` (factories with the signatures of
    ``WorkerPool`` and ``LoadSampler``; default: those) are the driver's
    seams to the world: ``ramps.testing.memory`` gives in-memory ones, so
    tests drive the real driver and core with ``start(threaded=False)`` and
    ``step()``."""

    #: the core's actions applied (made in ``__init__`` after the parts it uses; ``LoadReports`` calls it)
    outbound: Outbound

    def __init__(self, settings: NodeSettings, *, registry: Registry | None = None,
                 on_note: Callable[[Note], None] | None = None, transport: Transport | None = None,
                 clock: Clock = REAL_CLOCK, worker_pool: Callable[..., WorkerPoolLike] = WorkerPool,
                 load_sampler: Callable[..., SamplerLike] = LoadSampler, incarnation: int | None = None) -> None:
        """The driver's state and its parts get their first value; nothing
        starts before ``start``."""
        if not settings.robot:
            raise ValueError("a node needs a robot name")
        self.s = settings
        self.clock = clock
        self._given_transport = transport
        self._worker_pool = worker_pool
        self._load_sampler = load_sampler
        self._threaded = True
        self._incarnation = incarnation  # None: drawn at start (tests fix it, so a run repeats)
        self.robot = settings.robot
        self.team = settings.team
        self.registry = node_registry(registry or default_registry, settings.programs, settings.commands)
        #: the driver's queue: (kind, ...) items (``Inbound.handle``)
        self._q: queue.SimpleQueue[tuple[Any, ...]] = queue.SimpleQueue()
        #: its publishers, and the threads that send large messages
        self.outbox = Outbox(self.robot, lambda: self.transport)
        self._stopped = threading.Event()
        self._started = False
        #: its backlog of received bytes, what it makes of them, and the drops it counts
        self.intake = WireIntake(self.robot)
        self.heap = HeapTrimmer()  # gives the memory of a drained burst back (ramps.runtime.heap)
        self.trace = NodeTrace(self.robot, clock)
        self.transport: Transport | None = None
        #: its subscriptions, publishers and tokens on the transport
        self.membership = Membership(self.team, self.robot)
        self.node: Node | None = None
        #: the core's clock: the time this node was awake, its stalls taken out
        self.awake = AwakeClock(clock, lease_s=settings.lease_ms / 1000.0, robot=self.robot, trace=self.trace)
        #: the robot's cores, speed and quota, where its load is measured (``RobotMeasure.measure`` at start)
        self.measured = RobotMeasure(settings, clock, self.robot)
        #: rounds that stopped handling queued items to send what was due (ROUND_SECONDS), and whether
        #: the last left held messages (``WireIntake.later``) for the next round, which then waits for nothing
        self.rounds_cut, self.rounds_behind = 0, False
        #: the core's next deadline as the last round left it (its driver thread alone touches the core)
        self._deadline: tuple[float | None] | None = None
        #: teammates whose liveliness went just after a stall, held a moment
        self.held_lost = HeldLosses(self.awake, STALL_GRACE)
        #: its clients' requests, their outcomes and updates
        self.clients = ClientAnswers(self, settings, clock=clock, awake=self.awake, registry=self.registry,
                                     outbox=self.outbox)
        #: secured team: the newest revocation list, the robots it names (``revocations``, ``revoked_self``)
        self.revoked = Revoked(self.team, self.robot)
        #: the other nodes under this robot's name, and why this one left for one (``name_taken``)
        self.same_name = SameName(self.team, self.robot, self.trace)
        #: what it does with each input, and whether it heard any teammate (``lonely``)
        self.inbound = Inbound(self, settings, put=self._q.put, intake=self.intake, revoked=self.revoked,
                               held_lost=self.held_lost, trace=self.trace, clients=self.clients)
        #: Prometheus metrics (``--metrics``), fed from the driver thread (ramps.runtime.metrics)
        self.metrics: NodeMetrics | None = None
        #: the durable record of the programs this node is origin of (``state_dir``;
        #: ramps.runtime.store; how many it resumed at start: ``clients.restored``)
        self.store: OriginStore | None = None
        #: its periodic load reports and those of the instant
        self.reports = LoadReports(self, settings, apply=lambda actions: self.outbound.apply(actions), put=self._q.put,
                                   awake=self.awake, measured=self.measured, membership=self.membership,
                                   trace=self.trace, intake=self.intake)
        #: the core's actions applied to its parts and to the world
        parts = NodeParts(robot=self.robot, team=self.team, clock=clock, awake=self.awake, outbox=self.outbox,
                          trace=self.trace, intake=self.intake, membership=self.membership, revoked=self.revoked,
                          same_name=self.same_name)
        self.outbound = Outbound(self, parts, clients=self.clients, reports=self.reports, on_note=on_note,
                                 stop=lambda: self._q.put(("stop", threading.Event())), put=self._q.put)
        self.outbound.restart_when_split = settings.restart_when_split
        #: called on the driver thread after every round of its loop (systemd's watchdog, ramps.runtime.service)
        self.on_turn: Callable[[], None] | None = None

    # ================================================================ lifecycle
    def start(self, *, threaded: bool = True) -> "NodeRuntime":
        """Join the team and start driving. ``threaded=False``: no driver
        thread; the caller drives it with ``step()`` (tests)."""
        s = self.s
        creds, exit_on_failure = join_checks(self.s)
        if creds is not None:
            self.revoked.load(creds)
        m = self.measured
        m.measure()
        self.cores, self.speed, self.load_scope = m.cores, m.speed, m.scope
        # its start time and random bits: a node started later has a larger one (ramps.core.identity)
        self.incarnation = self._incarnation or new_incarnation(self.clock.time(), int.from_bytes(os.urandom(4), "big"))
        self.same_name.incarnation = self.incarnation
        return_freed_memory()
        self.accel = AcceleratorProbe(self.robot, resolve_accelerators(s.accelerators), team=self.team)
        self.node = Node(self.robot, cores=self.cores, speed=self.speed, policy=s.policy, config=core_config(s),
                         rng=random.Random(self.incarnation), incarnation=self.incarnation, bursts=True,
                         registry=self.registry.names(), program_weight=nice_weight(s.worker_nice),
                         core_fraction=m.core_fraction(), accelerators=self.accel.accelerators,
                         speed_class=m.speed_class())
        self.node.prompt_hold = PROMPT_HOLD  # one report of the instant a hold, made when it is over
        if s.state_dir not in ("", "off"):  # a foreign record: ConfigError, before anything starts
            self.store = OriginStore(s.state_dir, team=self.team, robot=self.robot, sync=s.state_sync)
            self.node.origin.changed = set()
        self.pool = self._worker_pool(self.cores, self.registry.targets(), self.inbound.finished,
                                      nice=worker_increment(s.worker_nice), on_progress=self.inbound.progress_reported,
                                      on_checkpoint=self.inbound.checkpoint_saved, core_share=m.core_fraction(),
                                      bundled=s.preload_bundled)
        self.pool.start()
        # programs on an accelerator are not CPU programs (ramps.core.accelerators)
        self.sampler = self._load_sampler(lambda: self.pool.busy() + self.pool.queued() - self.accel.held(),
                                          window=s.window,
                                          scope=m.scope, cgroup=m.cgroup if m.scope == "cgroup" else None,
                                          acct=m.acct if m.scope == "cgroup" else None)
        self.sampler.start()
        if s.trace:
            try:
                self.trace.open(s.trace, wire=s.trace_wire)
            except ConfigError:
                self._teardown()
                raise
        if s.metrics:
            self._serve_metrics(s.metrics)
        self._join_team(creds, exit_on_failure)
        self._threaded = threaded
        self._next_pub = self.awake.start()
        if s.connect or not s.multicast:  # else a lone robot on a LAN with multicast is no surprise
            self.inbound.lonely_at = self.clock.monotonic() + LONELY_AFTER
        if self.store is not None:
            self.outbound.apply(self.clients.restore(self.store, self._clock()))
        if threaded:
            self._driver = threading.Thread(target=self._drive, name=f"ramps-node-{self.robot}", daemon=True)
            self._driver.start()
        self._started = True
        if threaded and not gc.get_freeze_count():  # what start-up made lives as long as the process:
            gc.freeze()  # the collector's full passes leave it alone (once a process)
        log.info("node %s joined team %s: %d cores, speed %.2f, load scope %s", self.robot, self.team,
                 self.cores, self.speed, m.scope)
        return self

    def _join_team(self, creds: Credentials | None, exit_on_failure: bool) -> None:
        """Open the transport and take this node's place on it (``Membership.join``)."""
        try:
            self.transport = self._given_transport or ZenohTransport.open(self.s, credentials=creds,
                                                                          fail_fast=exit_on_failure)
            self.membership.join(self.transport, self.incarnation, on_wire=self._on_wire, put=self._q.put,
                                 on_where=self.same_name.on_where, revocations=self.revoked.secured,
                                 on_periodic=lambda data: self._on_wire(data, True))
        except TransportError as exc:
            self._teardown()
            raise TransportError(f"cannot join team {self.team!r} over Zenoh: {exc}") from exc
        except NotAdmitted:
            self._teardown()
            raise

    def _serve_metrics(self, address: str) -> None:
        from ramps.runtime.metrics import NodeMetrics

        self.metrics = NodeMetrics(self.robot, self.team, cores=self.cores, speed=self.speed, policy=self.s.policy)
        try:
            served = self.metrics.serve(address)
        except (OSError, ValueError) as exc:
            self.metrics = None
            self._teardown()
            raise ConfigError(f"cannot serve metrics on {address}: {getattr(exc, 'strerror', None) or exc}") from None
        log.info("node %s serves Prometheus metrics on http://%s:%d/metrics", self.robot, *served)

    def stop(self, timeout: float = 5.0) -> None:
        """Hand programs back, leave the team, stop workers. Idempotent."""
        if not self._started or self._stopped.is_set():
            return
        done = threading.Event()
        self._q.put(("stop", done))
        if self._threaded:
            done.wait(timeout)
            self._driver.join(timeout)
        else:
            while self.step():
                pass
        self._teardown()

    def wait(self, timeout: float | None = None) -> bool:
        return self._stopped.wait(timeout)

    def call(self, fn: Callable[[], Any], timeout: float = 5.0) -> Any:
        """Run ``fn`` on the driver thread (which owns the core) and return its result."""
        box: list[Any] = []
        ev = threading.Event()

        def run() -> None:
            box.append(fn())
            ev.set()

        self._q.put(("call", run))
        if not ev.wait(timeout):
            raise TimeoutError("the node's driver did not answer")
        return box[0]

    @property
    def bad_messages(self) -> int:
        """Messages dropped as bad input (``WireIntake``; ``ramps status``)."""
        return self.intake.bad

    @property
    def version_refused(self) -> int:
        """Of them, those refused as another major protocol version."""
        return self.intake.version_refused

    @property
    def unknown_types(self) -> int:
        """Of them, those skipped as a message type of a newer minor."""
        return self.intake.unknown_types

    @property
    def revocations(self) -> RevocationList | None:
        """The team's newest revocation list this node holds (a secured team)."""
        return self.revoked.current

    @property
    def name_taken(self) -> str:
        """Why this node left the team, another node under its name having started first ("" = it did not)."""
        return self.same_name.taken

    @property
    def split(self) -> str:
        """Why this node left the team to be restarted, a teammate heard one way only ("" = it did not)."""
        return self.outbound.split

    @property
    def revoked_self(self) -> bool:
        """Whether this robot was revoked by its team (then it leaves)."""
        return self.revoked.me

    def endpoints(self) -> list[str]:
        """Where this node listens (with the real ports)."""
        try:
            return self.transport.locators() if self.transport is not None else []
        except Exception:  # pragma: no cover - informational only
            return []

    def _teardown(self) -> None:
        self.membership.leave(self.transport)
        self.transport = None
        if getattr(self, "sampler", None):
            self.sampler.stop()
        if getattr(self, "pool", None):
            self.pool.stop()
        if getattr(self, "accel", None):
            self.accel.close()
        if self.metrics is not None:
            self.metrics.close()
        if self.store is not None:
            close_record(self.store)
            self.store = None
        self.trace.close()
        self._stopped.set()

    # ================================================================ inputs
    def _on_wire(self, data: bytes, periodic: bool = False) -> None:
        """Transport callback: queue the bytes for the driver, unless the backlog
        already holds MAX_BACKLOG_BYTES (a flood, or a driver that cannot keep
        up): then drop and count (``WireIntake.admit``), so memory stays
        bounded. Small messages (submits, heartbeats) pass any realistic burst.
        A teammate's ``periodic`` report, and a message that ``can_wait``, wait
        for the next round without waking the driver (``WireIntake.later``)."""
        self.heap.note(len(data))
        if self.intake.admit(len(data), MAX_BACKLOG_BYTES):
            (self.intake.later.append if periodic or can_wait(data) else self._q.put)(
                ("wire", data, self.clock.monotonic()))

    # ================================================================ driver
    def _clock(self) -> float:
        """The core's clock (``AwakeClock.read``): monotonic time less every stall of this node."""
        return self.awake.read()

    def _stall_told(self, now: float) -> list[Action]:
        """Tell the core about stalls, before anything that arrived meanwhile:
        a host's silence counts from the wake (``Origin.on_stalled``), and after
        one that may have closed links, teammates relink (``ramps.core.relink``)."""
        assert self.node is not None
        return self.node.handle(self.awake.told(), now)

    def _drive(self) -> None:
        while self._round(block=True):
            if self.on_turn is not None:
                self.on_turn()

    def step(self) -> bool:
        """One round of the driver without waiting: every queued item, then
        the timers due by the clock (publish, core deadlines, held
        teammates and outcomes). False once the node has stopped. For a
        node started with ``threaded=False`` (tests, ``ramps.testing.memory``)."""
        return self._round(block=False)

    def next_wake(self) -> float:
        """The clock's monotonic time at which the driver wants its next round
        (the time it allowed itself to sleep until)."""
        return self.awake.sleep_until

    def _round(self, *, block: bool) -> bool:
        node = self.node
        assert node is not None
        clock = self._clock
        q = self._q
        now = clock()
        known, self._deadline = self._deadline, None  # stepped (tests), the core may have been touched between
        deadline = known[0] if known is not None and block else node.next_deadline()
        next_pub = self._next_pub
        wake = next_pub if deadline is None else min(deadline, next_pub)
        wake = min(wake, self.held_lost.next_due()) if self.held_lost.held else wake
        wait = 0.0 if self.rounds_behind else max(0.0, min(wake, self.outbound.held_due(now)) - now)
        self.awake.sleep(wait)
        try:
            item = q.get(timeout=wait) if block else (None if q.empty() else q.get_nowait())
        except queue.Empty:
            item = None
        later = self.intake.later  # messages held (``_on_wire``): older than what woke this round
        if later:
            if item is not None:
                later.append(item)
            item = later.popleft()
        # every message queued before the timers fire: heartbeats and
        # results that piled up while the node stalled count first
        actions: list[Action] = []
        budget = MAX_ITEMS_PER_ROUND
        until = self.clock.monotonic() + ROUND_SECONDS
        behind = False  # items left queued: this robot's duties first, the origin's timeouts after them
        while item is not None:
            now = clock()
            if self.awake.pending:
                actions.extend(self._stall_told(now))
            if item[0] == "stop":
                self.outbound.apply(actions)
                self.outbound.shutdown(item[1])
                if self.revoked.me or self.same_name.taken or self.outbound.split:  # nobody asked: leave now
                    self._teardown()
                return False
            try:
                actions.extend(self.inbound.handle(item, now))
            except Exception:  # a bug must not take the node down; say so loudly
                log.exception("node %s: error handling %s", self.robot, item[0])
            if len(actions) >= 256:
                self.outbound.apply(actions)
                actions = []
            budget -= 1
            if budget <= 0 or self.clock.monotonic() >= until:
                behind = bool(later) or not q.empty()
                self.rounds_cut += behind
                break
            item = later.popleft() if later else None if q.empty() else q.get_nowait()  # this thread alone takes
        self.rounds_behind = behind and bool(later)  # what is held: the next round at once, not at a timer
        now = clock()
        if self.awake.pending:
            actions.extend(self._stall_told(now))
        if self.held_lost.held:
            actions.extend(self.inbound.release_lost(now))
        if now >= next_pub:
            self.outbound.publish(now)
            self.heap.maybe_trim(self.intake.backlog)
            self.inbound.look_lonely(self.clock.monotonic())
            period = self.s.publish_period
            self._next_pub = now + period if now - next_pub > period else next_pub + period
        deadline = node.next_deadline()
        if deadline is not None and deadline <= now:
            actions.extend(node.tick(now, origin=not behind))
            deadline = node.next_deadline()
        self._deadline = (deadline,)  # applying the actions leaves the core alone
        self.outbound.apply(actions)
        self.outbound.flush_held(now)
        if not block:  # the next round is due at the earliest of its timers
            wake = self._next_pub
            wake = wake if deadline is None else min(wake, deadline)
            wake = min(wake, self.held_lost.next_due()) if self.held_lost.held else wake
            self.awake.sleep(max(0.0, min(wake, self.outbound.held_due(now)) - now))
        return True

def run_node(settings: NodeSettings, *, install_signals: bool = True) -> NodeRuntime:
    """Start a node and block until SIGINT/SIGTERM, then shut it down cleanly."""
    import signal

    prioritize(settings.node_nice)
    rt = NodeRuntime(settings).start()
    stop = threading.Event()
    if install_signals:
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, lambda *_: stop.set())
    try:
        while not stop.wait(0.5) and not rt.wait(0):
            pass
    finally:
        rt.stop()
    return rt


__all__ = ["DROP_LOG_PERIOD", "OUTCOME_HOLD", "STALL_GRACE", "NodeRuntime", "prioritize", "run_node"]
