"""What a node's driver does with the core's actions.

How this works: ``Outbound`` is a part of the node's driver
(``ramps.runtime.node``), given at construction the parts it sends
through (``NodeParts``, and the clients' and load reports' parts); of the
driver it reads only what ``OutboundDriver`` names, what
the driver has once started (the core, its worker pool and accelerators,
its record and metrics, its transport). ``apply`` turns each action of the
core into its effect: ``Send`` is published to the teammate's inbox (a
result's acknowledgement after the round's outcomes; ``Outbox``: DROP under congestion, the core survives lost messages; a
message over 60 KB waits for room instead, on a thread of its own
destination, and an offer sent so tells the core when it is on its way and
when it is through: ``OfferSending``), ``StartProgram`` and ``StopProgram`` go to the worker pool
(or an accelerator's slot), ``Deliver`` becomes the client's outcome
(``ClientAnswers``), ``Note`` a client update, a trace line and a log
line, ``NameTaken`` (another node under this robot's name, ``SameName``)
this node's leaving or a line saying the other leaves; programs it hosts
for other origins are traced as this robot runs them
(``NodeTrace.hosted``). ``PublishReport`` (a report of the instant: the
programs running here changed, made by the core once its hold is over) goes
to ``LoadReports``, the newest of a batch only, after the batch's messages; ``publish`` has it publish the
periodic load report, and the team's revocation list when it is due again
(``Revoked``). ``shutdown`` hands running programs back and cancels this
origin's.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Protocol

from ramps.core.events import (
    Action,
    Cancel,
    Deliver,
    NameTaken,
    Note,
    OfferSending,
    Progress,
    PublishReport,
    Send,
    StartProgram,
    StopProgram,
)
from ramps.core.messages import Heartbeat, OffloadAccepted, OffloadRequest, ProgramResult, ResultAck, encode
from ramps.core.speed import MIN_RUN_WORK
from ramps.runtime import keys, revocation

if TYPE_CHECKING:
    from ramps.core.node import Node
    from ramps.runtime.accelerators import AcceleratorProbe, Grant
    from ramps.runtime.metrics import NodeMetrics
    from ramps.runtime.node_clients import ClientAnswers
    from ramps.runtime.node_parts import NodeParts
    from ramps.runtime.node_reports import LoadReports
    from ramps.runtime.node_seams import WorkerPoolLike
    from ramps.runtime.store import OriginStore
    from ramps.runtime.transport import Transport

log = logging.getLogger("ramps.node")
#: core notes a client hears about (ProgramUpdate.state), as placed/running/host_failed
_CLIENT_STATES = {"placed": "placed", "accepted": "running", "failed": "host_failed"}
#: messages that may go before the durable record of their round is written (``before_record``)
SAFE_BEFORE_RECORD = frozenset({OffloadRequest, OffloadAccepted, ProgramResult, Heartbeat})
#: programs found far from their declaration that are named in a warning, at most
MISDECLARED_WARNED = 1024


def before_record(actions: list[Action]) -> int:
    """How many of ``actions``, from the first, may take effect before the
    durable record of their round is written: offers to hosts and a host's
    answers (``SAFE_BEFORE_RECORD``), programs started, reports of the
    instant, and notes that tell no client anything at once. None of them
    tells a client that its program is taken, nor a host that its result is
    kept: a node that dies before the record is written leaves its client's
    submission unacknowledged, so the client submits it again to the
    restarted node (``ramps.runtime.pending.SUBMIT_RESEND``), and a host's
    result for a program the restarted node does not know is dropped.
    (Records and messages are final classes: their exact types are looked up.)"""
    for i, a in enumerate(actions):
        if type(a) is Send:
            if type(a.msg) not in SAFE_BEFORE_RECORD:
                return i
        elif type(a) is Note:
            if a.what == "failed" or (a.what == "placed" and a.attempt > 1):
                return i  # told at once (``TOLD_AT_ONCE``)
        elif type(a) is not StartProgram and type(a) is not PublishReport:
            return i
    return len(actions)


class OutboundDriver(Protocol):
    """What ``Outbound`` reads of its driver: what the driver has once started
    (None before ``start``, or once it let go of it)."""

    node: Node | None
    transport: Transport | None
    pool: WorkerPoolLike
    accel: AcceleratorProbe
    #: the durable record of the programs this node is origin of
    store: OriginStore | None
    metrics: NodeMetrics | None
    incarnation: int


class Outbound:
    """The outputs of ``driver``'s node, robot ``parts.robot`` of team ``parts.team``:
    the core's actions applied to its parts and to the world."""

    def __init__(self, driver: OutboundDriver, parts: NodeParts, *, clients: ClientAnswers, reports: LoadReports,
                 on_note: Callable[[Note], None] | None, stop: Callable[[], None],
                 put: Callable[[tuple[Any, ...]], None]) -> None:
        self.d = driver
        self.robot, self.team, self.clock, self.awake = parts.robot, parts.team, parts.clock, parts.awake
        self.outbox, self.trace, self.intake = parts.outbox, parts.trace, parts.intake
        self.membership, self.same_name, self.revoked = parts.membership, parts.same_name, parts.revoked
        self.clients, self.reports = clients, reports
        self.on_note = on_note
        #: asks the driver to stop (this node leaves: another under its name started first)
        self._stop = stop
        #: queues an item for the driver (from another thread)
        self._put = put
        #: programs whose calls were found far from their declaration, said once each
        self.misdeclared_warned: set[str] = set()
        #: leave when a teammate is heard one way only (``NodeSettings.restart_when_split``), and why it left
        self.restart_when_split = False
        self.split = ""

    def apply(self, actions: list[Action]) -> None:
        """Each of the core's ``actions``, in order, to its effect, except
        that a host's acknowledgements of results go last, after the outcomes
        their callers wait for. With a durable record, what changed is
        written first (``ClientAnswers.persist``), after only the leading
        actions that tell nobody anything a restart must keep
        (``before_record``): offers and programs started go out while it is
        written."""
        d = self.d
        store = d.store
        first = before_record(actions) if store is not None else -1
        metrics = d.metrics
        mnow = self.awake.now() if metrics is not None else 0.0  # the core's clock, for metrics' latencies
        traced = self.trace.on
        prompt = None  # the newest report of the instant: the only one of a batch that goes out
        acks: list[Send] = []
        for i, a in enumerate(actions):
            if i == first:
                assert store is not None
                self.clients.persist(store, actions)
            if metrics is not None:
                metrics.on_action(a, d.node, mnow)
            if traced and isinstance(a, (StartProgram, StopProgram, Send)):
                self.trace.hosted(a, closing=d.node is not None and d.node.executor.closing)
            if isinstance(a, Send):
                if type(a.msg) is ResultAck:
                    acks.append(a)
                else:
                    self._send(a)
            elif isinstance(a, StartProgram):
                if a.accelerator:  # when one of its slots is free (AcceleratorProbe.start)
                    d.accel.start((a.program_id, a.attempt), a.accelerator, self._runner(a))
                else:
                    d.pool.run((a.program_id, a.attempt), a.program, a.args, a.resume)
            elif isinstance(a, StopProgram):
                d.pool.cancel((a.program_id, a.attempt))
                d.accel.release((a.program_id, a.attempt))
            elif isinstance(a, Deliver):
                if traced:  # first, so a caller holding the result finds it traced
                    self.trace.write("delivered", a.program_id, a.host, a.attempts, a.error_kind)
                self.clients.deliver(a)
            elif isinstance(a, PublishReport):
                prompt = a.report
            elif isinstance(a, Progress):
                self.clients.progressed(a.program_id, a.fraction, a.detail, a.host, a.attempt)
            elif isinstance(a, NameTaken):
                if self.same_name.clash(a):  # this node started later: it leaves
                    self._stop()
            elif isinstance(a, Note):
                self._note(a)
        if store is not None and first >= len(actions):
            self.clients.persist(store, actions)
        for a in acks:
            self._send(a)
        if prompt is not None:  # the core held it (``Node.prompt_hold``): the changes that followed go with it
            self.reports.publish_prompt(prompt)

    def _send(self, a: Send) -> None:
        """``a``'s message to its teammate's inbox (``Outbox.send``)."""
        self.outbox.send(keys.inbox(self.team, a.to), encode(self.robot, a.msg),
                         self._on_way(a.msg) if isinstance(a.msg, OffloadRequest) else None)
        if self.trace.wire:
            self.trace.write("tx", getattr(a.msg, "program_id", ""), a.to, getattr(a.msg, "attempt", 0),
                             type(a.msg).__name__)

    def _on_way(self, offer: OffloadRequest) -> Callable[[bool], None]:
        """What tells the core that ``offer``, sent whole on its destination's
        thread, is on its way or through (``OfferSending``; on that thread)."""
        def on_way(done: bool) -> None:
            self._put(("progress", OfferSending(program_id=offer.program_id, attempt=offer.attempt, done=done)))
        return on_way

    def _note(self, a: Note) -> None:
        """A note of the core: a client's update, a trace line, a log line, ``on_note``."""
        if a.what in _CLIENT_STATES and a.program_id in self.clients.clients:
            state = _CLIENT_STATES[a.what]
            self.clients.update(a.program_id, "replaced" if state == "placed" and a.attempt > 1 else state,
                                a.robot, a.attempt)
        if self.trace.on:
            self.trace.write(a.what, a.program_id, a.robot, a.attempt, a.detail)
        if a.what in ("blacklisted", "unblacklisted", "failed", "anomaly"):
            log.info("node %s: %s %s %s %s", self.robot, a.what, a.robot, a.program_id, a.detail)
        elif a.what == "misdeclared":
            self._warn_misdeclared(a)
        elif a.what == "one_way":  # a split Zenoh session (ramps.core.oneway): only a restart heals it
            log.warning("node %s: teammate %s is heard one way only: %s. Restarting either node heals it "
                        "(docs/deploying.md, Leaving, crashing and restarting)", self.robot, a.robot, a.detail)
            if self.restart_when_split and not self.split:
                self.split = f"teammate {a.robot} is heard one way only ({a.detail})"
                log.error("node %s: leaving the team to be restarted (restart_when_split): %s", self.robot, self.split)
                self._stop()
        elif a.what == "two_way":
            log.warning("node %s: teammate %s is heard both ways again", self.robot, a.robot)
        if self.on_note is not None:
            self.on_note(a)

    def held_due(self, now: float) -> float:
        """The core's time at which something held is due: an outcome to look
        at again, a client's update (inf: none)."""
        return self.clients.held_due(now)

    def flush_held(self, now: float) -> None:
        """Send what is held and due by the core's time ``now``."""
        self.clients.flush(now)

    def _runner(self, a: StartProgram) -> Callable[[Grant | None], None]:
        """How to start ``a`` in a worker once its accelerator slot is granted."""
        def run(grant: Grant | None) -> None:
            self.d.pool.run((a.program_id, a.attempt), a.program, a.args, a.resume,
                            None if grant is None else grant.as_wire())
        return run

    def _warn_misdeclared(self, note: Note) -> None:
        """A call took far more or less than its program declares: said once
        per program (every call is in the trace and the metric)."""
        assert self.d.node is not None
        ap = self.d.node.origin.programs.get(note.program_id)
        program = ap.submit.program if ap is not None else note.program_id
        warned = self.misdeclared_warned
        if program in warned or len(warned) >= MISDECLARED_WARNED:
            return
        warned.add(program)
        log.warning("node %s: %s on %s; placements learn only from runs of at least %g work units, so declare "
                    "what a call really does (@ramps.program(work=...) or team.options(work=...))",
                    self.robot, note.detail, note.robot, MIN_RUN_WORK)

    def publish(self, now: float) -> None:
        """The periodic load report (``LoadReports.publish``), and the team's
        revocation list when it is due again (``Revoked.republish``)."""
        self.reports.publish(now)
        data = self.revoked.republish(now) if self.d.transport is not None else None
        if data is not None:
            self.outbox.put(revocation.revoked_key(self.team), data)

    def shutdown(self, done: threading.Event) -> None:
        """This node leaves: running programs are handed back to their origins
        and, with no record to keep them, the programs this node is origin of
        are cancelled; ``done`` is set then."""
        d = self.d
        # before its liveliness goes: a client (ramps top) tells this from a crash (not when the name
        # is another node's: that node stays)
        if d.transport is not None and not self.same_name.taken:
            self.membership.say_leaving(d.transport)
        now = self.awake.read()
        node = d.node
        assert node is not None
        out: list[Action] = []
        handed = node.executor.hand_back(now, out)
        if d.store is None:  # nothing keeps them: tell their clients
            for pid, ap in list(node.origin.programs.items()):
                if ap.state not in ("done", "failed"):
                    out.extend(node.handle(Cancel(program_id=pid), now))
        self.apply(node._loopback(out, now))
        if d.store is not None and node.origin.active():
            log.info("node %s keeps %d program(s) in its record %s for its next start", self.robot,
                     node.origin.active(), d.store.path)
        self.clients.flush_outcomes(leaving=True)
        log.info("node %s leaving team %s: handed back %d program(s)", self.robot, self.team, handed)
        if self.intake.bad or self.intake.overflow:  # what `ramps status` counted as dropped, both kinds
            log.warning("node %s dropped %d malformed message(s) and %d over its backlog while it ran", self.robot,
                        self.intake.bad, self.intake.overflow)
        self.clock.sleep(0.05)  # let Zenoh flush the hand-backs
        done.set()
