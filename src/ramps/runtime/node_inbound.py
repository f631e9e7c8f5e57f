"""What reaches a node's driver: teammates' messages, clients' requests, liveliness, revocations.

How this works: ``Inbound`` is a part of the node's driver
(``ramps.runtime.node``), given at construction the parts it hands inputs
to; of the driver it reads only what ``InboundDriver`` names, what the
driver has once started (the core, its accelerators, metrics and
transport). The worker pool's callbacks (``finished``, ``progress_reported``,
``checkpoint_saved``, on the pool's threads) only queue an item for the
driver, which takes each queued item on its own thread and hands it to
``handle``: bytes from the wire are decoded (a bad message is counted and
dropped: ``WireIntake``, ``ramps.runtime.node_intake``), a client's
submission goes to ``ramps.runtime.node_clients``, a teammate's message, a
program's end or progress to the core. A teammate's liveliness becomes
``PeerAlive``/``PeerLost`` for the core, except that just after this node
stalled a loss is held for ``STALL_GRACE`` (``HeldLosses``: it may be only
the teammate's lease on this frozen node that ran out). On a secured team,
a newer revocation list signed by the team CA (``Revoked``) shuts the
robots it names out (or makes this robot leave). A node that has heard no
teammate ``LONELY_AFTER`` seconds after it started says so (``lonely``).
A robot that comes to place programs (an application connected, or a
first program) hears every teammate's periodic reports from then on
(``Membership.widen``); its clients' requests wait (``held``) until its
teammates' newest reports are in (``("views",)``), so its first placement
sees the team.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Protocol

import msgspec

from ramps.core.events import (
    Action,
    ApplicationHere,
    Cancel,
    CheckpointSaved,
    PeerAlive,
    PeerLost,
    ProgramFinished,
    ProgressReported,
    Received,
)
from ramps.core.messages import (
    CancelSubmitted,
    Heartbeat,
    LoadReport,
    ProgramOutcome,
    ProgramUpdate,
    SubmitProgram,
)
from ramps.core.relink import RELINK_TIMEOUT
from ramps.runtime.node_seams import Key

if TYPE_CHECKING:
    from ramps.core.node import Node
    from ramps.runtime.accelerators import AcceleratorProbe
    from ramps.runtime.metrics import NodeMetrics
    from ramps.runtime.node_awake import HeldLosses
    from ramps.runtime.node_clients import ClientAnswers
    from ramps.runtime.node_intake import WireIntake
    from ramps.runtime.node_revoked import Revoked
    from ramps.runtime.node_team import Membership
    from ramps.runtime.node_trace import NodeTrace
    from ramps.runtime.settings import NodeSettings
    from ramps.runtime.transport import Clock, Transport

log = logging.getLogger("ramps.node")
#: seconds after a stall during which a teammate's lost liveliness is held,
#: in case it is only its lease on this stalled node that ran out (the core
#: does not count a teammate's silence for as long: ramps.core.relink)
STALL_GRACE = RELINK_TIMEOUT
#: a node told to --connect somewhere, or with multicast off, that has heard
#: no teammate this many seconds after it started says so, once (``Inbound.look_lonely``)
LONELY_AFTER = 8.0


class InboundDriver(Protocol):
    """What ``Inbound`` reads of its driver: what the driver has once started
    (None before ``start``, or once it let go of it)."""

    node: Node | None
    transport: Transport | None
    accel: AcceleratorProbe
    metrics: NodeMetrics | None
    membership: Membership
    clock: Clock

    def endpoints(self) -> list[str]: ...


class Inbound:
    """The inputs of ``driver``'s node, of settings ``s``, which queues its
    items with ``put``: each to the part or the core it is for."""

    def __init__(self, driver: InboundDriver, s: NodeSettings, *, put: Callable[[tuple[Any, ...]], None],
                 intake: WireIntake, revoked: Revoked, held_lost: HeldLosses, trace: NodeTrace,
                 clients: ClientAnswers) -> None:
        self.d = driver
        self.s, self.robot, self.team = s, s.robot, s.team
        self._put = put
        self.intake, self.revoked, self.held_lost = intake, revoked, held_lost
        self.trace, self.clients = trace, clients
        #: when to look whether this node has heard any teammate, on the clock's
        #: monotonic time (None: looked, or no need), and the warning it gave ("" = none)
        self.lonely_at: float | None = None
        self.lonely = ""
        #: clients' requests that wait for this origin's first views of its teammates
        self.held: list[SubmitProgram | CancelSubmitted] = []

    # the worker pool's callbacks (on its threads): each only queues an item for the driver
    def finished(self, key: Key, ok: bool, value: bytes, error: str, retryable: bool, cpu_s: float | None = None,
                 died: bool = False) -> None:
        self._put(("finished", ProgramFinished(program_id=key[0], attempt=key[1], ok=ok, value=value, error=error,
                                               result_size=len(value), retryable=retryable, cpu_s=cpu_s,
                                               worker_died=died)))

    def checkpoint_saved(self, key: Key, state: bytes, fraction: float | None) -> None:
        self._put(("progress", CheckpointSaved(program_id=key[0], attempt=key[1], state=state,
                                               fraction=fraction if isinstance(fraction, float) else None)))

    def progress_reported(self, key: Key, fraction: float, detail: str) -> None:
        self._put(("progress", ProgressReported(program_id=key[0], attempt=key[1], fraction=fraction,
                                                detail=detail)))

    def on_liveliness(self, robot: str, alive: bool, now: float) -> list[Action]:
        """A teammate's liveliness token came or went. Just after this node
        stalled, a loss is held for STALL_GRACE and forgotten if the robot
        comes back meanwhile (``HeldLosses``); a robot that does not is lost
        then (``release_lost``)."""
        if robot in self.revoked.robots:
            return []
        if not alive and not self.held_lost.lost(robot, now):
            return []
        if alive and self.held_lost.back(robot):  # its link is back: the core counts its silence again
            self.trace.write("peer_back", "", robot, 0, "lost and back while this node recovered from a stall")
        return self._peer_event(robot, alive, now)

    def _peer_event(self, robot: str, alive: bool, now: float) -> list[Action]:
        """A teammate's liveliness, to the core: its origin (the teammate as a
        host) and its executor (the teammate as an origin: one gone for good
        has its programs here stopped, see ``Executor.on_origin_lost``)."""
        assert self.d.node is not None
        if alive:
            self.d.membership.alive.add(robot)
        else:
            self.d.membership.alive.discard(robot)
        return self.d.node.handle(PeerAlive(robot=robot) if alive else PeerLost(robot=robot), now)

    def _on_revocations(self, data: bytes, now: float) -> list[Action]:
        """A revocation list from the team: adopt it if it is newer and signed
        by the team CA; shut the newly revoked robots out (or leave, if this
        robot is one of them). Anything else is remote bad input: counted.
        Only a node with the team CA (a secured team) subscribes to them."""
        if not self.revoked.secured:
            return []
        try:
            new = self.revoked.adopt(data)
        except Exception as exc:  # CredentialsError, or anything odd in a foreign message
            self.intake.refused("a revocation list", exc, now)
            return []
        rl = self.revoked.current
        if new is None or rl is None:
            return []
        out: list[Action] = []
        for robot in new:
            self.trace.write("revoked", "", robot, 0, f"list {rl.seq}")
            if robot == self.robot:
                continue
            log.warning("node %s: robot %s is revoked by the team (list %d): shut out", self.robot, robot, rl.seq)
            self.held_lost.forget(robot)
            self.d.membership.alive.discard(robot)
            assert self.d.node is not None
            self.d.node.executor.stop_origin(robot, now, out)
            out.extend(self.d.node.handle(PeerLost(robot=robot), now))
        if self.revoked.me:
            log.error("node %s: this robot is revoked by team %s (list %d): handing programs back and leaving",
                      self.robot, self.team, rl.seq)
            self._put(("stop", threading.Event()))
        return out

    def release_lost(self, now: float) -> list[Action]:
        """The teammates whose held loss falls due by ``now``, lost for the core."""
        return [a for robot in self.held_lost.due(now) for a in self._peer_event(robot, False, now)]

    def handle(self, item: tuple[Any, ...], now: float) -> list[Action]:
        """A queued ``item`` (its kind first), taken by the driver at the core's
        time ``now``: what the core is to do about it."""
        kind = item[0]
        node = self.d.node
        m = self.d.membership
        if not m.wide and node is not None and node.submits:  # e.g. programs resumed from its durable record
            m.widen(self.d.transport)
        if kind == "wire":  # a message the wire refuses needs no core to be dropped and counted
            env = self.intake.decode(item[1], now)
            if env is None:
                return []
            msg = env.msg
            assert node is not None
            if self.revoked.shuts_out(env.sender):  # refused at the ramps layer (see ramps.runtime.revocation)
                return []
            if self.trace.wire:
                self.trace.write("rx", getattr(msg, "program_id", ""), env.sender, getattr(msg, "attempt", 0),
                                  f"{type(msg).__name__} queued {now - item[2]:.3f} s", at=item[2])
            if isinstance(msg, (SubmitProgram, CancelSubmitted)):
                if not m.ready:  # placed once its teammates' newest reports are in
                    m.widen(self.d.transport)
                    self.held.append(msg)
                    return []
                return self._request(msg, now)
            if isinstance(msg, (ProgramOutcome, ProgramUpdate)):
                return []
            if isinstance(msg, LoadReport) and msg.robot != env.sender:
                self.intake.refused("a load report in another robot's name", None, now)
                return []
            if type(msg) is Heartbeat:  # read at this round: its silence counts from its arrival
                return node.handle(Received(sender=env.sender, msg=msg,
                                            at=now - max(0.0, self.d.clock.monotonic() - item[2])), now)
            return node.handle(Received(sender=env.sender, msg=msg), now)
        assert node is not None
        if kind == "finished":
            if self.d.metrics is not None:
                self.d.metrics.on_finished(item[1])
            held = self.d.accel.release((item[1].program_id, item[1].attempt))  # the next on its slot starts
            return node.handle(item[1] if held is None else msgspec.structs.replace(item[1], slot_s=held), now)
        if kind == "speed":  # the measurement's moment on the grid, its own figure, the node's
            if self.trace.on:
                self.trace.write("speed_measured", "", "", 0,
                                  f"{item[3]:.5g} at {item[2]:.1f}, node figure {item[1].speed:.5g}, se {item[1].se:.3g}")
            return node.handle(item[1], now)
        if kind == "progress":
            return node.handle(item[1], now)
        if kind == "live":
            robot, alive = item[1], item[2]
            if robot == self.robot:
                return []
            if self.trace.wire:
                self.trace.write("peer_alive" if alive else "peer_lost", "", robot, 0, "liveliness")
            return self.on_liveliness(robot, alive, now)
        if kind == "app":  # an application connected to submit here (its token came)
            if item[1]:
                m.widen(self.d.transport)
            return node.handle(ApplicationHere(), now) if item[1] else []
        if kind == "views":  # the query for the teammates' newest reports is over: what waited goes
            if m.ready:
                return []
            m.ready = True
            log.info("node %s: %d newest load reports fetched (its own among them); %d requests waited for them",
                     self.robot, m.fetched, len(self.held))
            self.trace.write("views", "", "", 0, f"{m.fetched} reports fetched")
            waiting, self.held = self.held, []
            return [a for msg in waiting for a in self._request(msg, now)]
        if kind == "call":
            item[1]()
            return []
        if kind == "revoked":
            return self._on_revocations(item[1], now)
        raise ValueError(f"unknown queue item {kind!r}")

    def _request(self, msg: SubmitProgram | CancelSubmitted, now: float) -> list[Action]:
        """A client's submission or cancellation, to the part it is for."""
        if isinstance(msg, SubmitProgram):
            return self.clients.submit(msg, now)
        node = self.d.node
        assert node is not None
        pid = self.clients.requests.get((msg.client, msg.request_id))
        if pid is None or node.origin.programs[pid].state in ("done", "failed"):
            return []
        return node.handle(Cancel(program_id=pid), now)

    def look_lonely(self, t: float) -> None:
        """At the clock's monotonic time ``t``, once past ``lonely_at``
        (LONELY_AFTER seconds after start): if no teammate was ever heard
        (no load report, no liveliness), log one warning saying what this
        node tried and what to check. It runs on: a lone robot is legal."""
        if self.lonely_at is None or t < self.lonely_at:
            return
        self.lonely_at = None
        assert self.d.node is not None
        if self.d.membership.alive or any(r != self.robot for r in self.d.node.view.robots()):
            return
        s = self.s
        tried = []
        if s.connect:
            tried.append(f"connecting to {', '.join(s.connect)}")
        if s.mode != "client":
            tried.append(f"listening on {', '.join(self.d.endpoints() or s.listen_endpoints())}")
        tried.append("multicast discovery " + ("on" if s.multicast else "off"))
        try:
            sessions = len(self.d.transport.peers()) if self.d.transport is not None else 0
        except Exception:
            sessions = 0
        if sessions:
            why = (f"it is linked to {sessions} Zenoh session(s), but none is a node of team {self.team!r} (an "
                   "application's ramps.connect() is not one): check that every robot runs with the same --team "
                   "(env RAMPS_TEAM)"
                   + (" and the same --secure setting" if not s.secure else ""))
        else:
            why = ("it is linked to no one: check that --connect names an endpoint a teammate's node listens on "
                   "(its --listen, shown as 'listening on' when it starts; e.g. --listen tcp/0.0.0.0:7447 there, "
                   "--connect tcp/ITS-IP:7447 here), that a firewall lets it through, and on loopback or a "
                   "network without multicast, run every node with --no-multicast and --connect/--listen")
        self.lonely = (f"node {self.robot} has heard no teammate in team {self.team!r} {LONELY_AFTER:g} s after "
                       f"starting ({'; '.join(tried)}); {why}. It keeps running: a lone robot runs its "
                       "programs itself")
        log.warning(self.lonely)
