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
program name and the arguments against the program's signature before it
places anything, so a bad call fails at the caller.

Shutdown (SIGINT/SIGTERM, ``stop()``): the executor hands every running
program back to its origin (a retryable result, so the origin places it
elsewhere at once), programs this node is origin of are cancelled and their
clients told, then the liveliness token, subscribers and transport close.

The driver reaches the team only through ``ramps.runtime.transport`` (a
Zenoh session in production, ``ramps.testing.memory`` in tests) and reads
time only from its injected clock.
"""

from __future__ import annotations

import json
import logging
import math
import os
import queue
import random
import threading
from collections import deque
from typing import Any, Callable

import msgspec

from ramps.core.cost import nice_weight
from ramps.core.events import (
    Cancel,
    CheckpointSaved,
    Deliver,
    Note,
    PeerAlive,
    PeerLost,
    ProgramFinished,
    Progress,
    ProgressReported,
    PublishReport,
    Received,
    Send,
    StartProgram,
    StopProgram,
    Submit,
)
from ramps.core.messages import (
    CancelSubmitted,
    LearnedWork,
    LinkSeen,
    LoadReport,
    ProgramOutcome,
    MAX_LISTED,
    ProgramUpdate,
    RunningProgram,
    SubmitProgram,
    WireError,
    decode,
    encode,
)
from ramps.core.node import Node
from ramps.core.policy import POLICIES
from ramps.core.program import ProgramState
from ramps.core.relink import RELINK_TIMEOUT, Stalled
from ramps.core.speed import REMEASURE_PERIOD, SpeedMeasured
from ramps.errors import ConfigError, NotAdmitted, ProgramNotFound, TransportError
from ramps.runtime import keys, revocation
from ramps.runtime.measure import LoadSampler, cgroup_dirs, cgroup_quota, detect_cores, measure_speed
from ramps.runtime.registry import Registry, decode_args, default_registry
from ramps.runtime.security import admission, settings_credentials
from ramps.runtime.settings import NodeSettings
from ramps.runtime.transport import REAL_CLOCK, Clock, Transport, ZenohTransport
from ramps.runtime.workers import WorkerPool

log = logging.getLogger("ramps.node")
#: core notes a client hears about (ProgramUpdate.state), as placed/running/host_failed
_CLIENT_STATES = {"placed": "placed", "accepted": "running", "failed": "host_failed"}
#: bytes of received messages waiting for the driver before new ones are dropped
MAX_BACKLOG_BYTES = 64 * 1024 * 1024
#: seconds between two log lines about dropped messages (each is counted)
DROP_LOG_PERIOD = 1.0
#: a driver that wakes this much later than it allowed itself was stalled
#: (frozen, starved of CPU, paused): see NodeRuntime._clock
STALL_MIN = 0.5
#: seconds after a stall during which a teammate's lost liveliness is held,
#: in case it is only its lease on this stalled node that ran out (the core
#: does not count a teammate's silence for as long: ramps.core.relink)
STALL_GRACE = RELINK_TIMEOUT
#: a stall this long, as a fraction of the Zenoh lease, may have let
#: teammates' leases on this node run out and their links close (Zenoh sends
#: keep-alives every quarter lease): the core is told (``Stalled``), so it
#: waits for their links before counting silence
RELINK_LEASE_FRACTION = 0.75
#: queued items handled before the timers fire (the rest after them)
MAX_ITEMS_PER_ROUND = 10_000
#: answered client requests remembered, so a resent submission is not run twice
ANSWERED_KEPT = 65536
#: bytes of recent outcomes kept, so one a client asks for again (its link
#: lapsed while it was sent: it went nowhere) is sent again
OUTCOMES_KEPT_BYTES = 16 * 1024 * 1024
#: seconds an outcome waits for its client to be reachable, and between two looks
OUTCOME_HOLD = 30.0
OUTCOME_RETRY = 0.05

INSECURE_WARNING = (
    "INSECURE: team {team!r} runs without authentication or encryption: anyone who can reach this network "
    "can join it, read its traffic, submit programs and run them on this robot. To secure it: "
    "`ramps team init`, `ramps team add ROBOT`, then `ramps node --secure --credentials DIR` (README, Security).")
_insecure_warned = False


class NodeRuntime:
    """One robot's node. ``transport`` (default: a Zenoh session opened
    from ``settings`` at ``start()``), ``clock`` (default: the real one),
    ``worker_pool`` and ``load_sampler`` (factories with the signatures of
    ``WorkerPool`` and ``LoadSampler``; default: those) are the driver's
    seams to the world: ``ramps.testing.memory`` gives in-memory ones, so
    tests drive the real driver and core with ``start(threaded=False)`` and
    ``step()``."""

    def __init__(self, settings: NodeSettings, *, registry: Registry | None = None,
                 on_note: Callable[[Note], None] | None = None, transport: Transport | None = None,
                 clock: Clock = REAL_CLOCK, worker_pool: Callable[..., Any] = WorkerPool,
                 load_sampler: Callable[..., Any] = LoadSampler, incarnation: int | None = None) -> None:
        if not settings.robot:
            raise ValueError("a node needs a robot name")
        self.s = settings
        self.clock = clock
        self._given_transport = transport
        self._worker_pool = worker_pool
        self._load_sampler = load_sampler
        self._threaded = True
        self._incarnation = incarnation  # None: random (tests fix it, so a run repeats)
        self.robot = settings.robot
        self.team = settings.team
        self.registry = Registry(dict((registry or default_registry)._specs))
        self.registry.load_entry_points()  # packages that declare ramps.programs
        for target in settings.programs:
            self.registry.add_target(target)
        for name, cmd in settings.commands.items():  # executables (ramps.runtime.command)
            self.registry.add_command(name, cmd.path, timeout=cmd.timeout, args=cmd.args, work=cmd.work,
                                      local_only=cmd.local_only)
        self.on_note = on_note
        self._q: queue.SimpleQueue = queue.SimpleQueue()
        self._clients: dict[str, tuple[str, int]] = {}
        self._requests: dict[tuple[str, int], str] = {}
        #: requests already answered (the newest ANSWERED_KEPT), in answer order, with
        #: their outcome as sent while it is among the newest OUTCOMES_KEPT_BYTES
        self._answered: dict[tuple[str, int], bytes | None] = {}
        self._kept_outcomes: deque[tuple[str, int]] = deque()
        self._kept_bytes = 0
        #: the newest progress of programs this node is origin of, until delivered
        self._progress: dict[str, tuple[float, str]] = {}
        self._seq = 0
        self._pubs: dict[str, Any] = {}
        self._stopped = threading.Event()
        self._started = False
        self.bad_messages = 0
        #: messages dropped because the driver's backlog was full, and its size
        self.overflow = 0
        self._sees: frozenset[str] = frozenset()  # teammates in this robot's view at the last report
        self._backlog_bytes = 0
        #: a flood of bad messages is logged one line per DROP_LOG_PERIOD
        self._drop_logged_at = -DROP_LOG_PERIOD
        self._drops_unlogged = 0
        self._trace = None
        self._trace_wire = False
        self.transport: Transport | None = None
        self.node: Node | None = None
        #: the driver's stalls (see _clock): how many, seconds in all
        self.stalls = 0
        self.stalled_s = 0.0
        self._stall_offset = 0.0
        self._stalled_at = 0.0
        self._remeasure_at: float | None = None
        #: a stall long enough to close links, not yet told to the core (seconds)
        self._stall_pending = 0.0
        self._relink_after = settings.lease_ms / 1000.0 * RELINK_LEASE_FRACTION
        self._last_read = 0.0
        self._sleep_until = 0.0
        #: teammates whose liveliness went just after a stall: robot -> core time it counts as lost
        self._held_lost: dict[str, float] = {}
        #: messages waiting for their receiver to be reachable: (key, bytes, monotonic deadline, block)
        self._held_outcomes: list[tuple[str, bytes, float, bool]] = []
        #: secured team: the newest revocation list, the robots it names, the CA that signs it
        self.revocations: revocation.RevocationList | None = None
        self._revoked: frozenset[str] = frozenset()
        self._ca_cert = None
        self._revocation_file: str | None = None
        self._republish_at = 0.0
        #: messages dropped because their sender is revoked; this robot itself was revoked
        self.revoked_dropped = 0
        self.revoked_self = False
        #: Prometheus metrics (``--metrics``), fed from the driver thread (ramps.observe.metrics)
        self.metrics = None

    # ================================================================ lifecycle
    def start(self, *, threaded: bool = True) -> "NodeRuntime":
        """Join the team and start driving. ``threaded=False``: no driver
        thread; the caller drives it with ``step()`` (tests)."""
        s = self.s
        creds, exit_on_failure = self._join_checks()
        if creds is not None:
            self._load_revocations(creds)
        cg, acct = cgroup_dirs()
        quota = cgroup_quota(cg)
        scope = s.load_scope
        if scope == "auto":
            scope = "cgroup" if quota is not None else "host"
        self.cores = s.cores or detect_cores()
        self.speed = s.speed or measure_speed(quota=quota, cores=self.cores)
        # a speed measured at boot is measured again while no program runs
        # (robots booting together measure each other's start-up; ramps.core.speed)
        self._quota = quota
        self._remeasure_at = None if s.speed else self.clock.monotonic() + REMEASURE_PERIOD
        self.incarnation = self._incarnation or int.from_bytes(os.urandom(6), "big")
        return_freed_memory()
        self.node = Node(self.robot, cores=self.cores, speed=self.speed, policy=s.policy, config=s.core,
                         rng=random.Random(self.incarnation), incarnation=self.incarnation,
                         registry=self.registry.names(), program_weight=nice_weight(s.worker_nice))
        self.pool = self._worker_pool(self.cores, self.registry.targets(), self._finished, nice=s.worker_nice,
                               on_progress=self._progress_reported, on_checkpoint=self._checkpoint_saved)
        self.pool.start()
        self.sampler = self._load_sampler(lambda: self.pool.busy() + self.pool.queued(), window=s.window,
                                   scope=scope, cgroup=cg if scope == "cgroup" else None,
                                   acct=acct if scope == "cgroup" else None)
        self.sampler.start()
        self.load_scope = scope
        # a cgroup's CPU use is in host cores; a robot of ``cores`` emulated at a
        # smaller quota reports it in its own cores, as its speed is scaled
        self._busy_scale = (self.cores / quota if scope == "cgroup" and quota is not None and quota < self.cores
                            else 1.0)
        if s.trace:
            try:
                self._trace = open(s.trace, "a", buffering=1)
            except OSError as exc:
                self._teardown()
                raise ConfigError(f"cannot write the trace file {s.trace}: {exc.strerror or exc}") from None
            self._trace_wire = s.trace_wire
        if s.metrics:
            self._serve_metrics(s.metrics)
        try:
            self.transport = self._given_transport or ZenohTransport.open(s, credentials=creds,
                                                                          fail_fast=exit_on_failure)
            put = self._q.put
            t = self.transport
            self._subs = [
                t.subscribe(keys.inbox(self.team, self.robot), self._on_wire),
                t.subscribe(keys.load(self.team), self._on_wire),
                t.subscribe_liveliness(keys.alive(self.team),
                                       lambda key, alive: put(("live", keys.robot_of(key), alive)), history=True),
            ]
            if self._ca_cert is not None:
                self._subs.append(t.subscribe(revocation.revoked_key(self.team),
                                              lambda _key, data: put(("revoked", data))))
            self._load_pub = t.publisher(keys.load(self.team, self.robot))
            self._token = t.declare_token(keys.alive(self.team, self.robot))
        except TransportError as exc:
            self._teardown()
            raise TransportError(f"cannot join team {self.team!r} over Zenoh: {exc}") from exc
        except NotAdmitted:
            self._teardown()
            raise
        self._threaded = threaded
        self._last_read = self.clock.monotonic()
        self._next_pub = self._clock()
        if threaded:
            self._driver = threading.Thread(target=self._drive, name=f"ramps-node-{self.robot}", daemon=True)
            self._driver.start()
        self._started = True
        log.info("node %s joined team %s: %d cores, speed %.2f, load scope %s", self.robot, self.team,
                 self.cores, self.speed, scope)
        return self

    def _serve_metrics(self, address: str) -> None:
        from ramps.observe.metrics import NodeMetrics

        self.metrics = NodeMetrics(self.robot, self.team, cores=self.cores, speed=self.speed, policy=self.s.policy)
        try:
            self.metrics.serve(address)
        except (OSError, ValueError) as exc:
            self.metrics = None
            self._teardown()
            raise ConfigError(f"cannot serve metrics on {address}: {getattr(exc, 'strerror', None) or exc}") from None
        log.info("node %s serves Prometheus metrics on http://%s:%d/metrics", self.robot, *self.metrics.address)

    def _join_checks(self):
        """Secure mode: this robot's checked credentials, and whether Zenoh may
        fail fast (every connect endpoint admitted them; see
        ``security.admission``, which raises ``NotAdmitted`` when the team
        refuses them). Insecure mode: say so, once per process."""
        global _insecure_warned
        s = self.s
        if not s.secure:
            if not _insecure_warned:
                _insecure_warned = True
                log.warning(INSECURE_WARNING.format(team=s.team))
            return None, False
        creds = settings_credentials(s, robot=self.robot)
        everyone = admission(s.connect, creds, team=self.team)
        if s.connect and not everyone:
            log.info("node %s: not every teammate at %s answers yet; Zenoh keeps trying", self.robot,
                     ", ".join(s.connect))
        return creds, everyone

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
        self._q.put(("call", lambda: (box.append(fn()), ev.set())))
        if not ev.wait(timeout):
            raise TimeoutError("the node's driver did not answer")
        return box[0]

    def endpoints(self) -> list[str]:
        """Where this node listens (with the real ports)."""
        try:
            return self.transport.locators() if self.transport is not None else []
        except Exception:  # pragma: no cover - informational only
            return []

    def _teardown(self) -> None:
        for attr in ("_token",):
            obj = getattr(self, attr, None)
            if obj is not None:
                try:
                    obj.undeclare()
                except Exception:
                    pass
        for sub in getattr(self, "_subs", []):
            try:
                sub.undeclare()
            except Exception:
                pass
        if self.transport is not None:
            try:
                self.transport.close()
            except Exception:
                pass
            self.transport = None
        if getattr(self, "sampler", None):
            self.sampler.stop()
        if getattr(self, "pool", None):
            self.pool.stop()
        if self.metrics is not None:
            self.metrics.close()
        if self._trace is not None:
            self._trace_wire = False
            self._trace.close()
            self._trace = None
        self._stopped.set()

    # ================================================================ inputs
    def _on_wire(self, _key: str, data: bytes) -> None:
        """Transport callback: queue the bytes for the driver, unless the backlog
        already holds MAX_BACKLOG_BYTES (a flood, or a driver that cannot keep
        up): then drop and count, so memory stays bounded. Small messages
        (submits, heartbeats) pass any realistic burst."""
        if self._backlog_bytes + len(data) > MAX_BACKLOG_BYTES:
            self.overflow += 1
            return
        self._backlog_bytes += len(data)
        self._q.put(("wire", data, self.clock.monotonic()))

    def _finished(self, key, ok: bool, value: bytes, error: str, retryable: bool) -> None:
        self._q.put(("finished", ProgramFinished(program_id=key[0], attempt=key[1], ok=ok, value=value, error=error,
                                                 result_size=len(value), retryable=retryable)))

    def _checkpoint_saved(self, key, state: bytes, fraction: float | None) -> None:
        self._q.put(("progress", CheckpointSaved(program_id=key[0], attempt=key[1], state=state,
                                                 fraction=fraction if isinstance(fraction, float) else None)))

    def _progress_reported(self, key, fraction: float, detail: str) -> None:
        self._q.put(("progress", ProgressReported(program_id=key[0], attempt=key[1], fraction=fraction,
                                                  detail=detail)))

    # ================================================================ driver
    def _clock(self) -> float:
        """The core's clock: monotonic time less every stall of this node.

        A stall is a reading later than the driver allowed itself to be
        (``_sleep_until``, or the previous reading) by more than STALL_MIN: the
        process was frozen (SIGSTOP), starved of CPU on a busy robot, or
        paused in a long collection. Nothing could be heard meanwhile, so the
        core must not count that time as silence from its hosts (it would
        write off healthy programs, its own included, the moment the node
        wakes): the stall is taken out of the core's time. Deadlines stay
        as long in the time the node was awake to hear."""
        t = self.clock.monotonic()
        late = t - max(self._last_read, self._sleep_until)
        if late > STALL_MIN:
            self._stall_offset += late
            self.stalls += 1
            self.stalled_s += late
            self._stalled_at = t
            if late >= self._relink_after:
                self._stall_pending += late
            if self._trace is not None:
                self._write_trace("stalled", "", "", 0, f"{late:.3f}", at=t)
            log.warning("node %s: driver stalled for %.1f s (frozen, starved of CPU or paused); "
                        "that time does not count as silence from teammates", self.robot, late)
        self._last_read = t
        self._sleep_until = 0.0
        return t - self._stall_offset

    def _stall_told(self, now: float) -> list:
        """Tell the core about a stall that may have closed links (see
        ``ramps.core.relink``), before anything that arrived meanwhile."""
        seconds, self._stall_pending = self._stall_pending, 0.0
        return self.node.handle(Stalled(seconds=seconds), now)

    def _drive(self) -> None:
        while self._round(block=True):
            pass

    def step(self) -> bool:
        """One round of the driver without waiting: every queued item, then
        the timers due by the clock (publish, core deadlines, held
        teammates and outcomes). False once the node has stopped. For a
        node started with ``threaded=False`` (tests, ``ramps.testing.memory``)."""
        return self._round(block=False)

    def next_wake(self) -> float:
        """The clock's monotonic time at which the driver wants its next round
        (the time it allowed itself to sleep until)."""
        return self._sleep_until

    def _round(self, *, block: bool) -> bool:
        node = self.node
        clock = self._clock
        q = self._q
        now = clock()
        deadline = node.next_deadline()
        next_pub = self._next_pub
        wake = next_pub if deadline is None else min(deadline, next_pub)
        wake = min(wake, self._next_release()) if self._held_lost else wake
        wake = min(wake, now + OUTCOME_RETRY) if self._held_outcomes else wake
        wait = max(0.0, wake - now)
        self._sleep_until = self.clock.monotonic() + wait
        try:
            item = q.get(timeout=wait) if block else q.get_nowait()
        except queue.Empty:
            item = None
        # every message queued before the timers fire: heartbeats and
        # results that piled up while the node stalled count first
        actions: list = []
        budget = MAX_ITEMS_PER_ROUND
        while item is not None:
            now = clock()
            if self._stall_pending:
                actions.extend(self._stall_told(now))
            if item[0] == "stop":
                self._apply(actions)
                self._shutdown(item[1])
                if self.revoked_self:  # nobody asked: leave the team now (run_node and the CLI see wait())
                    self._teardown()
                return False
            try:
                actions.extend(self._handle(item, now))
            except Exception:  # a bug must not take the node down; say so loudly
                log.exception("node %s: error handling %s", self.robot, item[0])
            if len(actions) >= 256:
                self._apply(actions)
                actions = []
            budget -= 1
            try:
                item = q.get_nowait() if budget > 0 else None
            except queue.Empty:
                item = None
        now = clock()
        if self._stall_pending:
            actions.extend(self._stall_told(now))
        if self._held_lost:
            actions.extend(self._release_lost(now))
        if now >= next_pub:
            self._publish(now)
            period = self.s.publish_period
            self._next_pub = now + period if now - next_pub > period else next_pub + period
        deadline = node.next_deadline()
        if deadline is not None and deadline <= now:
            actions.extend(node.tick(now))
        self._apply(actions)
        if self._held_outcomes:
            self._flush_outcomes()
        if not block:  # the next round is due at the earliest of its timers
            wake = self._next_pub
            deadline = node.next_deadline()
            wake = wake if deadline is None else min(wake, deadline)
            wake = min(wake, self._next_release()) if self._held_lost else wake
            wake = min(wake, now + OUTCOME_RETRY) if self._held_outcomes else wake
            self._sleep_until = self.clock.monotonic() + max(0.0, wake - now)
        return True

    def _on_liveliness(self, robot: str, alive: bool, now: float) -> list:
        """A teammate's liveliness token came or went. Just after this node
        stalled, every teammate's lease on it may have run out: their links
        close and their tokens vanish here, then come back as soon as Zenoh
        reconnects. Such a loss is held for STALL_GRACE and forgotten if the
        robot comes back meanwhile; a robot that does not is lost then."""
        if robot in self._revoked:
            return []
        if not alive and self._stalled_at and self.clock.monotonic() - self._stalled_at < STALL_GRACE:
            self._held_lost[robot] = now + STALL_GRACE
            return []
        if alive and self._held_lost.pop(robot, None) is not None:
            if self._trace is not None:
                self._write_trace("peer_back", "", robot, 0, "lost and back while this node recovered from a stall")
            return self._peer_event(robot, True, now)  # its link is back: the core counts its silence again
        return self._peer_event(robot, alive, now)

    def _peer_event(self, robot: str, alive: bool, now: float) -> list:
        """A teammate's liveliness, to the origin (its hosts) and to the
        executor (its origins: one gone for good has its programs here
        stopped, see ``Executor.on_origin_lost``)."""
        if alive:
            self.node.executor.on_origin_back(robot)
        else:
            self.node.executor.on_origin_lost(robot, now)
        return self.node.handle(PeerAlive(robot=robot) if alive else PeerLost(robot=robot), now)

    # ================================================================ revocation
    def _load_revocations(self, creds) -> None:
        """Secured team: the list saved beside this robot's credentials, if
        any. A robot on it does not join (``NotAdmitted``)."""
        from ramps.runtime.security import _load_cert

        self._ca_cert = _load_cert(creds.ca, "team CA certificate")
        self._revocation_file = str(creds.cert.parent / revocation.REVOKED_FILE)
        rl = revocation.load(self._revocation_file, self._ca_cert, self.team)
        if rl is None:
            return
        if self.robot in rl.robots:
            raise NotAdmitted(f"robot {self.robot!r} is revoked by team {self.team!r} (revocation list {rl.seq} "
                              f"of {rl.issued}, {self._revocation_file}): it may not join the team")
        self.revocations, self._revoked = rl, frozenset(rl.robots)

    def _on_revocations(self, data: bytes, now: float) -> list:
        """A revocation list from the team: adopt it if it is newer and signed
        by the team CA; shut the newly revoked robots out (or leave, if this
        robot is one of them). Anything else is remote bad input: counted."""
        try:
            rl = revocation.decode(data, self._ca_cert, self.team)
        except Exception as exc:  # CredentialsError, or anything odd in a foreign message
            self.bad_messages += 1
            if now - self._drop_logged_at >= DROP_LOG_PERIOD:  # a flood is one line a period
                log.warning("node %s ignored a revocation list: %s", self.robot, exc)
                self._drop_logged_at = now
            return []
        if self.revocations is not None and rl.seq <= self.revocations.seq:
            return []
        new = sorted(set(rl.robots) - self._revoked)
        self.revocations, self._revoked = rl, frozenset(rl.robots)
        self._republish_at = 0.0  # pass it on now
        try:
            revocation.save(self._revocation_file, rl)
        except OSError as exc:
            log.warning("node %s could not save revocation list %d to %s: %s", self.robot, rl.seq,
                        self._revocation_file, exc)
        out: list = []
        for robot in new:
            if self._trace is not None:
                self._write_trace("revoked", "", robot, 0, f"list {rl.seq}")
            if robot == self.robot:
                self.revoked_self = True
                continue
            log.warning("node %s: robot %s is revoked by the team (list %d): shut out", self.robot, robot, rl.seq)
            self._held_lost.pop(robot, None)
            self.node.executor.stop_origin(robot, now, out)
            out.extend(self.node.handle(PeerLost(robot=robot), now))
        if self.revoked_self:
            log.error("node %s: this robot is revoked by team %s (list %d): handing programs back and leaving",
                      self.robot, self.team, rl.seq)
            self._q.put(("stop", threading.Event()))
        return out

    def _republish(self, now: float) -> None:
        if self.revocations is None or now < self._republish_at or self.transport is None:
            return
        self._republish_at = now + revocation.REPUBLISH_PERIOD
        self._put(revocation.revoked_key(self.team), revocation.encode(self.revocations))

    def _next_release(self) -> float:
        return min(self._held_lost.values())

    def _release_lost(self, now: float) -> list:
        out: list = []
        for robot, when in list(self._held_lost.items()):
            if when <= now:
                del self._held_lost[robot]
                out.extend(self._peer_event(robot, False, now))
        return out

    def _handle(self, item: tuple, now: float) -> list:
        kind = item[0]
        node = self.node
        if kind == "wire":
            self._backlog_bytes -= len(item[1])
            try:
                env = decode(item[1])  # the wire limit; client arguments are checked on submit
            except WireError as exc:
                self.bad_messages += 1
                if now - self._drop_logged_at < DROP_LOG_PERIOD:
                    self._drops_unlogged += 1
                else:
                    n = self._drops_unlogged
                    more = f" ({n} more dropped since the last such line)" if n else ""
                    log.warning("node %s dropped a message: %s%s", self.robot, exc, more)
                    self._drop_logged_at, self._drops_unlogged = now, 0
                return []
            msg = env.msg
            if env.sender in self._revoked:  # refused at the ramps layer (see ramps.runtime.revocation)
                self.revoked_dropped += 1
                return []
            if self._trace_wire:
                self._write_trace("rx", getattr(msg, "program_id", ""), env.sender, getattr(msg, "attempt", 0),
                                  f"{type(msg).__name__} queued {now - item[2]:.3f} s", at=item[2])
            if isinstance(msg, SubmitProgram):
                return self._client_submit(msg, now)
            if isinstance(msg, CancelSubmitted):
                pid = self._requests.get((msg.client, msg.request_id))
                if pid is None or node.origin.programs[pid].state in ("done", "failed"):
                    return []
                return node.handle(Cancel(program_id=pid), now)
            if isinstance(msg, (ProgramOutcome, ProgramUpdate)):
                return []
            if isinstance(msg, LoadReport) and msg.robot != env.sender:
                self.bad_messages += 1
                return []
            return node.handle(Received(sender=env.sender, msg=msg), now)
        if kind == "finished":
            if self.metrics is not None:
                self.metrics.on_finished(item[1])
            return node.handle(item[1], now)
        if kind in ("progress", "speed"):
            return node.handle(item[1], now)
        if kind == "live":
            robot, alive = item[1], item[2]
            if robot == self.robot:
                return []
            if self._trace_wire:
                self._write_trace("peer_alive" if alive else "peer_lost", "", robot, 0, "liveliness")
            return self._on_liveliness(robot, alive, now)
        if kind == "call":
            item[1]()
            return []
        if kind == "revoked":
            return self._on_revocations(item[1], now)
        raise ValueError(f"unknown queue item {kind!r}")

    def _client_submit(self, m: SubmitProgram, now: float) -> list:
        rkey = (m.client, m.request_id)
        if rkey in self._requests or rkey in self._answered:
            # a repeated request (clients resend until acknowledged, and ask again after
            # their link to this node lapsed): one program per request; answer where it stands
            return self._answer_again(rkey)
        self._seq += 1
        pid = f"{self.robot}#{self.incarnation % 100000}-{self._seq}"
        self._requests[rkey] = pid
        self._clients[pid] = rkey
        try:
            spec = self.registry.get(m.program)
            spec.check_args(decode_args(m.args))
        except ProgramNotFound as exc:
            return self._tell_client(pid, ok=False, error=str(exc), kind="refused", host=self.robot)
        except Exception as exc:  # signature mismatch, undecodable arguments
            return self._tell_client(pid, ok=False, kind="bad_arguments",
                                     error=f"bad arguments for program {m.program!r}: {exc}")
        if m.policy and m.policy not in POLICIES:
            return self._tell_client(pid, ok=False, kind="bad_arguments",
                                     error=f"unknown policy {m.policy!r}; choose one of {', '.join(POLICIES)}")
        if len(m.args) > self.s.max_args_bytes:
            return self._tell_client(pid, ok=False, kind="bad_arguments",
                                     error=f"arguments are {len(m.args)} bytes; the limit is {self.s.max_args_bytes}")
        return self.node.handle(Submit(
            program_id=pid, program=m.program, args=m.args, payload_size=len(m.args),
            work=m.work or spec.work, result_size=m.result_size or spec.result,
            local_only=m.local_only or spec.local_only, policy=m.policy, memory=spec.memory,
        ), now)

    def _tell_client(self, pid: str, *, ok: bool, value: bytes = b"", error: str = "", kind: str = "",
                     host: str = "", attempts: int = 0, moves: int = 0, resumed_from: float | None = None) -> list:
        target = self._clients.pop(pid, None)
        if target is None:
            return []
        client, request_id = target
        self._requests.pop(target, None)
        self._progress.pop(pid, None)
        data = encode(self.robot, ProgramOutcome(
            request_id=request_id, ok=ok, value=value, error=error, error_kind=kind, host=host, attempts=attempts,
            moves=moves, resumed_from=resumed_from))
        self._answered[target] = data  # a resend still in flight must not run it again
        self._kept_outcomes.append(target)
        self._kept_bytes += len(data)
        while self._kept_outcomes and (self._kept_bytes > OUTCOMES_KEPT_BYTES
                                       or len(self._kept_outcomes) > ANSWERED_KEPT):
            old_key = self._kept_outcomes.popleft()
            old = self._answered.get(old_key)
            if old is not None:
                self._kept_bytes -= len(old)
                self._answered[old_key] = None
        if len(self._answered) > ANSWERED_KEPT:
            old = self._answered.pop(next(iter(self._answered)))
            self._kept_bytes -= len(old) if old is not None else 0
        self._send_outcome(keys.client(self.team, client), data)
        return []

    def _answer_again(self, rkey: tuple[str, int]) -> list:
        """A client asked again about a request: its program's state if it
        runs (an update acknowledges the request), its outcome again if this
        node still keeps it (the first may have gone nowhere: the client's
        link lapsed while this node was stalled, and Zenoh may still report a
        match through another peer), else an outcome saying it is lost."""
        pid = self._requests.get(rkey)
        if pid is not None:
            ap = self.node.origin.programs.get(pid)
            if ap is None:
                self._update_client(pid, "placed", "", 0)
            else:
                self._update_client(pid, "running" if ap.state is ProgramState.RUNNING else "placed",
                                    ap.host or "", ap.attempt)
            return []
        data = self._answered.get(rkey)
        if data is None:
            data = encode(self.robot, ProgramOutcome(
                request_id=rkey[1], ok=False, error_kind="", host=self.robot, attempts=0,
                error=f"node {self.robot} answered this request long ago and no longer keeps its outcome"))
        self._send_outcome(keys.client(self.team, rkey[0]), data)
        return []

    def _send_outcome(self, key: str, data: bytes) -> None:
        """An outcome is sent once, never resent. If no subscriber of that
        client matches its key right now (after this node stalled, the
        client's link to it is being rebuilt: an outcome published then was
        lost, and the client waited for ever), it is held until one does, for
        OUTCOME_HOLD at most, then sent regardless."""
        self._send_or_hold(key, data, block=True, until=self.clock.monotonic() + OUTCOME_HOLD)

    def _send_or_hold(self, key: str, data: bytes, *, block: bool, until: float) -> None:
        if any(k == key for k, _, _, _ in self._held_outcomes) or not self._reachable(key, block):
            self._held_outcomes.append((key, data, until, block))
            return
        self._put(key, data, block=block)

    def _reachable(self, key: str, block: bool) -> bool:
        if self.transport is None:
            return True
        try:
            pub = self._pubs.get(key)
            if pub is None:
                pub = self._pubs[key] = self.transport.publisher(key, block=block)
            return bool(pub.matching())
        except Exception:  # cannot tell: send
            return True

    def _flush_outcomes(self) -> None:
        """Send what was held, per key in order, once its receiver is
        reachable or its time is up."""
        held, self._held_outcomes = self._held_outcomes, []
        now = self.clock.monotonic()
        waiting: set[str] = set()
        for key, data, until, block in held:
            if key in waiting or (now < until and not self._reachable(key, block)):
                waiting.add(key)
                self._held_outcomes.append((key, data, until, block))
            else:
                self._put(key, data, block=block)

    # ================================================================ outputs
    def _apply(self, actions: list) -> None:
        mnow = self.clock.monotonic() - self._stall_offset  # the core's clock, for metrics' latencies
        for a in actions:
            if self.metrics is not None:
                self.metrics.on_action(a, self.node, mnow)
            if isinstance(a, Send):
                self._put(keys.inbox(self.team, a.to), encode(self.robot, a.msg))
                if self._trace_wire:
                    self._write_trace("tx", getattr(a.msg, "program_id", ""), a.to, getattr(a.msg, "attempt", 0),
                                      type(a.msg).__name__)
            elif isinstance(a, StartProgram):
                self.pool.run((a.program_id, a.attempt), a.program, a.args, a.resume)
            elif isinstance(a, StopProgram):
                self.pool.cancel((a.program_id, a.attempt))
            elif isinstance(a, Deliver):
                kind = a.error_kind
                if self.node.executor.closing and kind == "cancelled":
                    kind, a = "shutdown", msgspec.structs.replace(a, error=f"origin {self.robot} shut down")
                if self._trace is not None:  # first, so a caller holding the result finds it traced
                    self._write_trace("delivered", a.program_id, a.host, a.attempts, a.error_kind)
                self._tell_client(a.program_id, ok=a.ok, value=a.value, error=a.error, kind=kind, host=a.host,
                                  attempts=a.attempts, moves=a.moves, resumed_from=a.resumed_from)
            elif isinstance(a, PublishReport):
                self._publish_prompt(a.report)
            elif isinstance(a, Progress):
                self._progress[a.program_id] = (a.fraction, a.detail)
                self._update_client(a.program_id, "progress", a.host, a.attempt)
            elif isinstance(a, Note):
                if a.what in _CLIENT_STATES and a.program_id in self._clients:
                    state = _CLIENT_STATES[a.what]
                    self._update_client(a.program_id, "replaced" if state == "placed" and a.attempt > 1 else state,
                                        a.robot, a.attempt)
                if self._trace is not None:
                    self._write_trace(a.what, a.program_id, a.robot, a.attempt, a.detail)
                if a.what in ("blacklisted", "unblacklisted", "failed", "anomaly"):
                    log.info("node %s: %s %s %s %s", self.robot, a.what, a.robot, a.program_id, a.detail)
                if self.on_note is not None:
                    self.on_note(a)

    def _update_client(self, pid: str, state: str, host: str, attempt: int) -> None:
        """Tell the program's client where it stands (advisory; see ProgramUpdate)."""
        target = self._clients.get(pid)
        if target is None:
            return
        fraction, detail = self._progress.get(pid, (None, ""))
        if self.transport is None:
            return
        data = encode(self.robot, ProgramUpdate(request_id=target[1], state=state, host=host, attempt=attempt,
                                                fraction=fraction, detail=detail))
        try:  # advisory: dropped rather than let a stalled client stall this driver (outcomes block, see _put)
            self.transport.put(keys.client(self.team, target[0]), data, block=False)
        except Exception as exc:
            log.debug("node %s could not send a program update: %s", self.robot, exc)

    def _write_trace(self, what: str, program_id: str, other: str, attempt: int, detail: str, *,
                     at: float | None = None) -> None:
        """One JSON line per decision: ``t`` is self.clock.monotonic() (one clock for
        every process of a host), ``wall`` the Unix time, fields as the
        simulator's trace (``ramps.sim.engine.TraceEntry``)."""
        rec = {"t": round(self.clock.monotonic() if at is None else at, 6), "wall": round(self.clock.time(), 6),
               "robot": self.robot, "what": what, "program_id": program_id, "other": other, "attempt": attempt,
               "detail": detail}
        try:
            self._trace.write(json.dumps(rec) + "\n")
        except OSError as exc:  # a full disk must not stop the node
            log.warning("node %s: trace file write failed, trace off: %s", self.robot, exc)
            self._trace = None
            self._trace_wire = False

    def _put(self, key: str, data: bytes, *, block: bool = False) -> None:
        """Publish on ``key``. Messages to robots use Zenoh's DROP congestion
        control: a frozen teammate must never stall this node's only driver
        thread, and the core already survives lost messages (connect
        timeouts, periodic heartbeats, results resent until acknowledged).
        Outcomes to a client (``block=True``) are not resent, so they wait."""
        if self.transport is None:
            return
        pub = self._pubs.get(key)
        try:
            if pub is None:
                pub = self._pubs[key] = self.transport.publisher(key, block=block)
                if len(self._pubs) > 4096:  # clients come and go
                    self._pubs.pop(next(iter(self._pubs))).undeclare()
            pub.put(data)
        except Exception as exc:
            log.warning("node %s could not publish on %s: %s", self.robot, key, exc)

    def _remeasure(self) -> None:
        """Measure this robot's speed again, off the driver's thread (briefly:
        0.05 s of CPU); the core keeps the figure if it is faster."""
        try:
            speed = measure_speed(0.05, quota=self._quota, cores=self.cores)
        except Exception:  # never worth a node
            log.exception("node %s: measuring its speed again failed", self.robot)
            return
        self._q.put(("speed", SpeedMeasured(speed=speed)))

    def _publish(self, now: float) -> None:
        due = self._remeasure_at
        if due is not None and self.clock.monotonic() >= due and not self.pool.busy() and not self.pool.queued():
            self._remeasure_at = self.clock.monotonic() + REMEASURE_PERIOD
            threading.Thread(target=self._remeasure, name=f"ramps-speed-{self.robot}", daemon=True).start()
        busy, runnable, ramps_avg = self.sampler.averages()
        per_core, load1, mem_free = self.sampler.extras()
        self.node.executor.background = max(0.0, runnable - ramps_avg)
        if self.load_scope == "cgroup":
            busy = min(busy * self._busy_scale, float(self.cores))
        report = self.node.make_report(cpu_busy=busy,
                                       runnable=runnable, ramps_avg=ramps_avg, window=self.s.window,
                                       mem_free=mem_free, cpu_per_core=per_core, load_avg=load1)
        sees = frozenset(self.node.view.candidates(now)) - {self.robot}
        if sees != self._sees:
            self._log_view_change(self._sees, sees)
            self._sees = sees
        report = msgspec.structs.replace(report, bad_messages=self.bad_messages + self.overflow,  # `ramps status`
                                         sees=len(sees), running=self._running_list(), **self._learned())
        self._last_report = report
        if self.metrics is not None:
            st = self.node.statistics()
            self.metrics.on_report(cpu_busy=busy, runnable=runnable, load_avg=load1, mem_free=mem_free,
                                   running=st.running, in_flight=st.active_programs, sees=len(sees),
                                   blacklisted=len(st.blacklisted), dropped=report.bad_messages,
                                   reports_received=st.reports_received)
        try:
            self._load_pub.put(encode(self.robot, report))
            if self._trace_wire:
                self._write_trace("tx", "", "*", 0, "LoadReport")
        except Exception as exc:
            log.warning("node %s could not publish its load: %s", self.robot, exc)
        self._republish(now)

    def _publish_prompt(self, report) -> None:
        """A report of the instant from the core (its programs changed), with
        what only the sampler measures taken from the last periodic report."""
        last = getattr(self, "_last_report", None)
        if last is not None:
            report = msgspec.structs.replace(report, mem_free=last.mem_free, cpu_per_core=last.cpu_per_core,
                                             load_avg=last.load_avg, bad_messages=last.bad_messages,
                                             sees=last.sees, links=last.links, learned=last.learned)
        # what it runs and whom it wrote off, as the periodic report says: without them
        # `ramps status`, `ramps top` and ROS diagnostics saw both flap to empty
        report = msgspec.structs.replace(report, running=self._running_list(),
                                         blacklisted=self.node.view.blacklisted())
        try:
            self._load_pub.put(encode(self.robot, report))
        except Exception as exc:
            log.warning("node %s could not publish its load: %s", self.robot, exc)

    def _learned(self) -> dict[str, list]:
        """What this node measured of its links and learned of its programs'
        work, for its load report (``ramps status``)."""
        def ok(x: float | None) -> float | None:  # within the schema, or the whole report would be refused
            return x if x is not None and math.isfinite(x) and x >= 0 else None

        measured = self.node.links.measured()
        factors = self.node.host_speeds.factor if self.node.host_speeds is not None else {}
        # teammates only: an origin also compares the runs on its own robot
        links = [(r, measured.get(r)) for r in sorted((set(measured) | set(factors)) - {self.robot})[:MAX_LISTED]]
        work = sorted(self.node.origin.learned_work().items())[:MAX_LISTED]
        return dict(links=[LinkSeen(r, ok(e.latency) if e else None, ok(e.bandwidth) if e else None,
                                    ok(factors.get(r))) for r, e in links],
                    learned=[LearnedWork(p, w) for p, w in work if ok(w) is not None])

    def _running_list(self) -> list[RunningProgram]:
        """The programs this robot runs, with their progress (``ramps status``)."""
        jobs = list(self.node.executor.running.values())[:MAX_LISTED]
        return [RunningProgram(j.program, j.origin, j.progress) for j in jobs]

    def _log_view_change(self, before: frozenset[str], after: frozenset[str]) -> None:
        """One line when teammates enter or leave this robot's view (the
        robots it could place programs on), so a log tells who it saw when."""
        def names(robots: frozenset[str]) -> str:
            shown = sorted(robots)
            return ", ".join(shown[:8]) + (f" and {len(shown) - 8} more" if len(shown) > 8 else "")

        parts = [f"+{names(after - before)}" if after - before else "",
                 f"-{names(before - after)}" if before - after else ""]
        log.info("node %s sees %d teammate(s): %s", self.robot, len(after), " ".join(p for p in parts if p))

    def _shutdown(self, done: threading.Event) -> None:
        now = self._clock()
        node = self.node
        out: list = []
        handed = node.executor.hand_back(now, out)
        for pid, ap in list(node.origin.programs.items()):
            if ap.state not in ("done", "failed"):
                out.extend(node.handle(Cancel(program_id=pid), now))
        self._apply(node._loopback(out, now))
        for key, data, _, block in self._held_outcomes:  # leaving: the last chance to send them
            self._put(key, data, block=block)
        self._held_outcomes = []
        log.info("node %s leaving team %s: handed back %d program(s)", self.robot, self.team, handed)
        if self.bad_messages:
            log.warning("node %s dropped %d malformed message(s) while it ran", self.robot, self.bad_messages)
        self.clock.sleep(0.05)  # let Zenoh flush the hand-backs
        done.set()


def return_freed_memory(threshold: int = 256 * 1024) -> None:
    """Make glibc hand large freed blocks back to the system at once.

    By default glibc raises its mmap threshold each time a large block is
    freed (up to 32 MiB), so later multi-megabyte messages are carved from the
    heap and stay resident after they are dropped: a flood with 1-9 MB garbage
    left a node 36-50 MB bigger (``ramps bench flood``), 1-22 MB with this. A
    fixed threshold keeps every block over ``threshold`` bytes (Python's and
    Zenoh's) in its own mapping, unmapped when freed. Other C libraries: no-op."""
    import ctypes

    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return
    m_mmap_threshold = -3  # glibc's M_MMAP_THRESHOLD
    mallopt(ctypes.c_int(m_mmap_threshold), ctypes.c_int(threshold))


def run_node(settings: NodeSettings, *, install_signals: bool = True) -> NodeRuntime:
    """Start a node and block until SIGINT/SIGTERM, then shut it down cleanly."""
    import signal

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


__all__ = ["NodeRuntime", "run_node"]
