"""The origin side of the protocol: every autonomous program this robot owns.

How this works: ``Origin`` keeps the robot's autonomous programs
(``programs``, and ``by_host``, the live ones by host) and turns each input
(a submission, a message about a program, a due timer, a teammate lost or
back) into a program event, which ``_step`` runs through
``ramps.core.program.TRANSITIONS``: the handler the table names, then a
check that the program is left in a state the table allows. Results are
delivered exactly once: a program keeps the attempts whose results it
still wants (``live``); anything else is acknowledged, so the host stops
resending, and discarded (``_route``).

The handlers are methods here (the table names them); where the work is
one idea of its own, it lives in a module of functions that sees the origin
through a ``Protocol`` of what it uses, and the method is one line:

- ``ramps.core.placing``: where a program's next attempt goes, and its offer;
- ``ramps.core.failures``: rejections, failed hosts, lost workers, the back-off;
- ``ramps.core.moves``: a relocation's move (``MOVING``), which
  ``ramps.core.relocation`` decides, every ``relocate_period``;
- ``ramps.core.deadlines``: deadlines, and ``on_miss`` when none can be met;
- ``ramps.core.silence``: when a host's silence is a failure, around this
  robot's own stalls;
- ``ramps.core.progress``: progress reports and checkpoints;
- ``ramps.core.durable``: programs restored from a previous process;
- ``ramps.core.burst``: a burst of submissions placed together (the node
  calls it at the end of a batch).

Its parts with state: ``Timers`` (the heap of every program's timer),
``Isolation`` (copies written off when it was this robot that was cut off,
revived), ``Relink`` (hosts whose links are not back after this robot's
stall) and ``Learning`` (the work learned from runs; a base class).

Rules: no clock (``now`` comes in), no I/O, randomness from the injected
``rng``. Remote misbehaviour (a message about a program we never had, an
illegal transition caused by a peer) is counted in ``anomalies`` and never
raises.
"""

from __future__ import annotations

import math
import random
from collections import deque
from typing import Any

from ramps.core import deadlines, durable, failures, moves, placing, progress, silence
from ramps.core.config import RampsConfig
from ramps.core.cost import NetworkEstimate
from ramps.core.events import Action, Deliver, Note, Send, Submit
from ramps.core.isolation import Isolation
from ramps.core.learning import Learning
from ramps.core.links import Links
from ramps.core.loadview import LoadView
from ramps.core.messages import (
    CancelProgram,
    Heartbeat,
    OffloadAccepted,
    OffloadRejected,
    ProgramCheckpoint,
    ProgramProgress,
    ProgramResult,
    ResultAck,
)
from ramps.core.policy import Placement, Policy, PlacementRequest, make_policy
from ramps.core.program import (FINAL, TRANSITIONS, AutonomousProgram, Event, IllegalTransition, ProgramState,
                                ProtocolError, resolve_handlers as resolve_handlers)
from ramps.core.relink import Relink
from ramps.core.relocation import relocation_check
from ramps.core.timers import Timers

S = ProgramState
E = Event


class Origin(Learning):
    def __init__(
        self,
        me: str,
        view: LoadView,
        policy: Policy,
        config: RampsConfig,
        rng: random.Random,
        net: NetworkEstimate,
    ) -> None:
        super().__init__()  # the learned work (``ramps.core.learning``)
        self.me = me
        self.view = view
        self.policy = policy
        self.config = config
        self.rng = rng
        self.net = net
        #: policies by name: the node's own, plus any a program asked for
        self._policies: dict[str, Policy] = {policy.name: policy}
        self.programs: dict[str, AutonomousProgram] = {}
        #: host -> its live program ids, in placement order (a set's order
        #: would follow the process's hash seed)
        self.by_host: dict[str, dict[str, None]] = {}
        #: teammate -> ids of programs offered to it, every one still offered there
        #: among them (``placing.queued_bytes``); delivered ones leave at once
        self.offered: dict[str, dict[str, None]] = {}
        #: program -> every host it was put under in ``by_host`` or ``offered`` (``deliver`` clears those)
        self.hosts_of: dict[str, set[str]] = {}
        self.timers = Timers()
        self.isolation = Isolation(me, view, config, self.programs, self._changed)
        #: finished programs, oldest first: kept for ``result_retention`` so a
        #: late result is settled (acknowledged, discarded), then forgotten
        self._finished: deque[tuple[float, str]] = deque()
        #: measured latency and bandwidth per teammate (set by the node)
        self.links: Links | None = None
        #: after this robot's own stall, the hosts whose links are not back yet
        self.relink = Relink(me)
        #: when anything but a load report last came from each teammate (``ramps.core.liveness``)
        self.heard: dict[str, float] = {}
        #: when the next relocation check is due (None: nothing running to move)
        self._relocate_due: float | None = None
        #: relocation checks price moves with a generator of their own, so
        #: turning relocation on leaves every placement's draws unchanged
        self.relocation_rng = random.Random(f"{me}/relocate")
        self.moves = 0
        self.moves_aborted = 0
        #: this robot's own stalls (``Stalled``, every one the driver saw): the
        #: seconds taken out of the core's clock in all, and the latest wake
        self.stalled_s = 0.0
        self.woke_at = -math.inf
        #: a host's silence counts from ``woke_at + wake_grace`` (see on_stalled)
        self.wake_grace = 0.0
        #: each host's speed correction as relocation last saw it, and since
        #: when (``ramps.core.relocation``: no move right after a change)
        self.factor_seen: dict[str, tuple[float, float]] = {}
        #: relocation checks that withheld a move on an uncertain estimate, by reason
        self.withheld: dict[str, int] = {}
        #: with ``bursts``, submitted programs wait in ``held`` for the driver's
        #: end of batch (``ramps.core.burst``: placed together); else placed at once
        self.bursts = False
        self.held: list[AutonomousProgram] = []
        #: teammates' claims on pools while a burst is placed (``ramps.core.claims``)
        self.claimed: dict[tuple[str, str], list[float]] = {}
        # statistics
        self.delivered = 0
        #: programs delivered after their deadline or refused as unmeetable
        self.deadline_misses = 0
        self.discarded = 0
        self.anomalies = 0
        self.placements = 0
        self.host_failures = 0
        self.rejections = 0
        #: programs changed since the driver last read this (``None``: nobody
        #: keeps a record; ``ramps.core.durable``)
        self.changed: set[str] | None = None
        #: restored programs offered to their host again and not answered yet: id -> attempt
        self.resumed: dict[str, int] = {}

    # ================================================================ inputs
    def submit(self, sub: Submit, now: float, out: list[Action]) -> None:
        if sub.program_id in self.programs:
            raise ValueError(f"program id {sub.program_id!r} was already submitted")
        if not (math.isfinite(sub.work) and sub.work >= 0):  # NaN work made every policy's choice fail
            raise ValueError(f"program {sub.program_id!r}: work must be finite and >= 0, got {sub.work!r}")
        deadlines.check(sub)
        if not (math.isfinite(sub.accelerator_work) and sub.accelerator_work >= 0):
            raise ValueError(f"program {sub.program_id!r}: accelerator_work must be finite and >= 0, "
                             f"got {sub.accelerator_work!r}")
        if not sub.accelerator and not sub.cpu_fallback:
            raise ValueError(f"program {sub.program_id!r}: cpu_fallback=False needs an accelerator kind")
        if sub.policy:
            self.add_policy(sub.policy)
        ap = self.programs[sub.program_id] = AutonomousProgram(sub, now)
        self._changed(ap)
        if self.bursts:
            self.held.append(ap)
        else:
            self.place(ap, now, out)

    def add_policy(self, name: str) -> None:
        """Know the policy ``name`` a program asked for (``ValueError`` names the known ones)."""
        if name not in self._policies:
            self._policies[name] = make_policy(name)

    def restore(self, programs: list[AutonomousProgram], now: float, out: list[Action]) -> None:
        """Resume programs a previous process of this robot owned (``ramps.core.durable``)."""
        durable.restore(self, programs, now, out)

    def _changed(self, ap: AutonomousProgram) -> None:
        if self.changed is not None:
            self.changed.add(ap.program_id)

    def cancel(self, program_id: str, now: float, out: list[Action]) -> None:
        ap = self.programs.get(program_id)
        if ap is None:
            raise KeyError(f"no program {program_id!r} was submitted here")
        if ap.state not in FINAL:
            self._step(ap, E.CANCEL, now, out, None)

    def on_accepted(self, msg: OffloadAccepted, now: float, out: list[Action]) -> None:
        self._route(msg.program_id, msg.attempt, msg.host, E.ACCEPTED, now, out, msg)

    def on_rejected(self, msg: OffloadRejected, now: float, out: list[Action]) -> None:
        self._route(msg.program_id, msg.attempt, msg.host, E.REJECTED, now, out, msg)

    def on_result(self, msg: ProgramResult, now: float, out: list[Action]) -> None:
        self._route(msg.program_id, msg.attempt, msg.host, E.RESULT, now, out, msg)

    def on_heartbeat(self, msg: Heartbeat, now: float, out: list[Action], *, heard: float | None = None) -> None:
        """``heard``: when it arrived, if the driver read it later (the silence counts from then)."""
        host, programs, heard = msg.host, self.programs, now if heard is None else heard
        for ref in msg.programs:
            ap = programs.get(ref.program_id)
            if (ap is not None and ap.state is S.RUNNING and ref.attempt == ap.attempt and host == ap.host
                    and ap.live.get(ref.attempt) == host):
                if heard > ap.last_heard:  # the table's RUNNING + heartbeat, the most common message of all, inline
                    ap.last_heard = heard
                continue
            self._route(ref.program_id, ref.attempt, host, E.HEARTBEAT, now, out, None)

    def on_progress(self, msg: ProgramProgress, now: float, out: list[Action]) -> None:
        """A host says how far a program is: passed on if the copy is still
        wanted (advisory, ``ramps.core.progress``; stale ones dropped)."""
        ap = self._wanted(msg.program_id, msg.attempt, msg.host)
        if ap is not None:
            progress.on_progress(ap, msg, now, out)

    def on_checkpoint(self, msg: ProgramCheckpoint, now: float, out: list[Action]) -> None:
        """A live copy saved its state: the latest is kept (``ramps.core.progress``)."""
        ap = self._wanted(msg.program_id, msg.attempt, msg.host)
        if ap is not None and progress.on_checkpoint(ap, msg, now, out):
            self._changed(ap)

    def _wanted(self, pid: str, attempt: int, host: str) -> AutonomousProgram | None:
        """The program, if ``attempt`` on ``host`` is a copy whose result it still wants."""
        ap = self.programs.get(pid)
        if ap is None or ap.state in FINAL or ap.live.get(attempt) != host:
            return None
        return ap

    def on_peer_lost(self, robot: str, now: float, out: list[Action]) -> None:
        self.view.set_lost(robot, True)
        for pid in list(self.by_host.get(robot, ())):
            ap = self.programs[pid]
            old = ap.moving_from
            if ap.state is S.MOVING and old is not None and old[1] == robot:
                # the copy a move is taking over from is gone: the move goes on
                moves.drop_old_copy(self, ap)
                self._changed(ap)
                out.append(Note(what="failed", program_id=pid, robot=robot, attempt=old[0],
                                detail="host_lost while moving away"))
            if ap.host == robot and ap.state in (S.OFFERED, S.RUNNING, S.MOVING):
                self._step(ap, E.HOST_LOST, now, out, None)
        self.isolation.check(now, out)

    def on_peer_alive(self, robot: str, now: float, out: list[Action]) -> None:
        self.view.set_lost(robot, False)
        durable.offer_again(self, robot, out)

    def on_stalled(self, seconds: float, now: float, *, links: bool = False) -> None:
        """This robot's driver did not run for ``seconds`` (taken out of the
        core's clock, so ``now`` is about when it stopped) and woke at
        ``now``: a host's silence counts from the wake (``ramps.core.silence``);
        relocation waits ``relocate_calm``."""
        silence.stalled(self, seconds, now, links=links)

    # ================================================================ timers
    def next_deadline(self) -> float | None:
        first = self.timers.first(self.programs)
        if self._relocate_due is not None and len(self.programs) <= len(self._finished):
            self._relocate_due = None  # every program has ended: nothing to move
        if self._relocate_due is not None and (first is None or self._relocate_due < first):
            first = self._relocate_due
        check = self.isolation.due()
        if check is not None and (first is None or check < first):
            return check
        return first

    def tick(self, now: float, out: list[Action]) -> None:
        self.isolation.tick(now, out)
        horizon = now - self.config.result_retention
        while self._finished and self._finished[0][0] < horizon:
            _, pid = self._finished.popleft()
            ap = self.programs.get(pid)
            if ap is not None and ap.state in FINAL:
                del self.programs[pid]
        for ap in self.timers.due(now, self.programs):
            kind = ap.timer
            if kind is not None and not silence.held_off(self, ap, kind, now):
                self._step(ap, kind, now, out, None)
        if self._relocate_due is not None and now >= self._relocate_due:
            self._relocate_due = None
            if self._relocation_check(now, out):
                self._relocate_due = now + self.config.relocate_period

    def relinked(self, host: str, now: float) -> None:
        """``host``'s link is back after this robot's stall (``ramps.core.relink``):
        its silence counts from now (``ramps.core.silence``)."""
        silence.relinked(self, host, now)

    # ================================================================ dispatch
    def _route(self, pid: str, attempt: int, host: str, event: Event, now: float, out: list[Action], msg: Any) -> None:
        ap = self.programs.get(pid)
        if ap is None:
            self._anomaly(out, pid, host, f"{event} for a program this robot never submitted")
            if event == E.RESULT:
                out.append(Send(to=host, msg=ResultAck(program_id=pid, attempt=attempt, origin=self.me)))
            return
        if attempt == ap.attempt and host == ap.host and ap.live.get(attempt) == host and ap.state is not S.BACKOFF:
            # the current attempt, still wanted (backing off, it is a copy kept or revived: below)
            self._step(ap, event, now, out, msg)
            return
        # about an attempt that is not the current one
        if event == E.RESULT:
            out.append(Send(to=host, msg=ResultAck(program_id=pid, attempt=attempt, origin=self.me)))
            if ap.state not in FINAL and (ap.live.get(attempt) == host or self.isolation.late(ap, attempt, host)):
                self._finish_with(ap, msg, now, out)
                self._changed(ap)
            else:
                self.discarded += 1
                out.append(Note(what="discarded", program_id=pid, robot=host, attempt=attempt,
                                detail="stale result from an attempt no longer wanted"))
        elif event in (E.ACCEPTED, E.HEARTBEAT):
            if ap.live.get(attempt) == host and ap.state not in FINAL:
                if ap.moving_from is not None and ap.moving_from[0] == attempt:
                    ap.moving_from[2] = now  # the copy a move takes over from still runs
                return  # an attempt kept alive while the origin was cut off, or moving away
            if self.isolation.late(ap, attempt, host):
                self.isolation.heard_again(ap, attempt, host, out)
                return
            # the host runs a copy nobody wants: stop it
            out.append(Send(to=host, msg=CancelProgram(program_id=pid, attempt=attempt, origin=self.me)))
        # a rejection of an old attempt needs nothing

    def _step(self, ap: AutonomousProgram, event: Event, now: float, out: list[Action], msg: Any) -> None:
        """Run the transition ``event`` takes from the program's state, then
        check it left the program in one of the states the table allows."""
        state = ap.state
        try:
            transition = ap.transition(event)
        except ProtocolError as exc:
            if event is E.CANCEL:
                raise  # the application's misuse
            self._anomaly(out, ap.program_id, ap.host or "", str(exc))  # a peer's doing
            return
        _HANDLERS[transition.handler](self, ap, now, out, msg, event)
        if event is not E.HEARTBEAT or ap.state is not state:
            self._changed(ap)
        allowed = transition.allowed(state)
        if ap.state not in allowed:
            raise IllegalTransition(ap.program_id, state, event, transition.handler, ap.state, allowed)

    def _anomaly(self, out: list[Action], pid: str, robot: str, detail: str) -> None:
        self.anomalies += 1
        out.append(Note(what="anomaly", program_id=pid, robot=robot, detail=detail))

    # ================================================================ handlers (the table's)
    def _ignore(self, ap: AutonomousProgram, now: float, out: list[Action], msg: Any, event: Event) -> None:
        pass

    def _place(self, ap: AutonomousProgram, now: float, out: list[Action], msg: Any, event: Event) -> None:
        self.place(ap, now, out)

    def _on_accepted(self, ap: AutonomousProgram, now: float, out: list[Action], msg: Any, event: Event) -> None:
        self.accept(ap, now, out, msg)

    def _on_heartbeat(self, ap: AutonomousProgram, now: float, out: list[Action], msg: Any, event: Event) -> None:
        ap.last_heard = now

    def _on_rejected(self, ap: AutonomousProgram, now: float, out: list[Action], msg: OffloadRejected,
                     event: Event) -> None:
        failures.on_rejected(self, ap, now, out, msg)

    def _on_host_failed(self, ap: AutonomousProgram, now: float, out: list[Action], msg: Any, event: Event) -> None:
        failures.on_host_failed(self, ap, now, out, event)

    def _on_result(self, ap: AutonomousProgram, now: float, out: list[Action], msg: ProgramResult,
                   event: Event) -> None:
        out.append(Send(to=msg.host, msg=ResultAck(program_id=ap.program_id, attempt=msg.attempt, origin=self.me)))
        self._finish_with(ap, msg, now, out)

    def _on_cancel(self, ap: AutonomousProgram, now: float, out: list[Action], msg: Any, event: Event) -> None:
        self.deliver(ap, now, out, ok=False, error="cancelled by the application", host=ap.host or "",
                     kind="cancelled")

    def _relocate(self, ap: AutonomousProgram, now: float, out: list[Action], msg: Placement, event: Event) -> None:
        moves.start(self, ap, msg, now, out)

    def _on_moved(self, ap: AutonomousProgram, now: float, out: list[Action], msg: Any, event: Event) -> None:
        moves.moved(self, ap, now, out, msg)

    def _on_move_failed(self, ap: AutonomousProgram, now: float, out: list[Action], msg: Any, event: Event) -> None:
        moves.move_failed(self, ap, now, out, msg, event)

    # ================================================================ what the parts ask of the origin
    def accept(self, ap: AutonomousProgram, now: float, out: list[Action], msg: Any) -> None:
        """The current attempt's host took it (its acceptance, or a heartbeat
        that overtook it): the program runs there, under heartbeat watch."""
        if isinstance(msg, OffloadAccepted):
            self.view.accepted(ap.placed_host, ap.program_id, ap.attempt, msg.accept_seq)
        ap.state = S.RUNNING
        ap.last_heard = now
        ap.rejections = 0
        ap.excluded.clear()
        ap.accepted_at = ap.done_at = now
        ap.ran_on[ap.placed_host] = None
        out.append(Note(what="accepted", program_id=ap.program_id, robot=ap.placed_host, attempt=ap.attempt))
        self.timers.set(ap, now + self.config.heartbeat_timeout, E.HEARTBEAT_TIMEOUT)
        if self._relocate_due is None and self._relocating():
            self._relocate_due = now + self.config.relocate_period

    def _finish_with(self, ap: AutonomousProgram, msg: ProgramResult, now: float, out: list[Action]) -> None:
        """A wanted copy's result: delivered, or, if its worker was lost, run again."""
        if not msg.ok and msg.retryable:
            failures.worker_lost(self, ap, msg, now, out)
            return
        self.leave_host(ap, msg.host, msg.finish_seq, attempt=msg.attempt)
        ap.live.pop(msg.attempt, None)
        if msg.ok and msg.work_done is not None:
            self._learn(ap, msg.attempt, msg.host, msg.work_done, out)
        self.deliver(ap, now, out, ok=msg.ok, value=msg.value, error=msg.error, host=msg.host,
                     kind="" if msg.ok else "program")

    def place(self, ap: AutonomousProgram, now: float, out: list[Action], *, host: str | None = None,
              placement: Placement | None = None, prefer: tuple[str, float] = ("", 0.0)) -> None:
        """Offer ``ap``'s next attempt (``ramps.core.placing``)."""
        placing.place(self, ap, now, out, host=host, placement=placement, prefer=prefer)

    def request(self, ap: AutonomousProgram, work: float, accel_work: float, left: float | None,
                prefer: tuple[str, float] = ("", 0.0)) -> PlacementRequest:
        """What the policy is asked to place for ``ap`` (``ramps.core.placing``)."""
        return placing.request(ap, work, accel_work, left, prefer)

    def exclusions(self, ap: AutonomousProgram, now: float, out: list[Action]) -> frozenset[str] | None:
        """The robots ``ap`` may not go to now (``ramps.core.placing``)."""
        return placing.exclusions(self, ap, now, out)

    def offer(self, ap: AutonomousProgram, out: list[Action]) -> None:
        """Offer the current attempt to its host again (``ramps.core.placing``)."""
        placing.offer(self, ap, out)

    def backoff(self, ap: AutonomousProgram, now: float, out: list[Action], *, certain: bool = False) -> None:
        """Back off, then place ``ap`` again, or give up (``ramps.core.failures``)."""
        failures.backoff(self, ap, now, out, certain=certain)

    def abandon_move(self, ap: AutonomousProgram, now: float, out: list[Action], why: str) -> None:
        """Give ``ap``'s move up (``ramps.core.moves``)."""
        moves.abandon(self, ap, now, out, why)

    def deliver(self, ap: AutonomousProgram, now: float, out: list[Action], *, ok: bool,
                value: bytes = b"", error: str = "", host: str = "", kind: str = "") -> None:
        """End ``ap`` with its result or error (exactly once), and stop every other copy."""
        for attempt, h in ap.live.items():  # stop every other copy
            out.append(Send(to=h, msg=CancelProgram(program_id=ap.program_id, attempt=attempt, origin=self.me)))
            self.leave_host(ap, h, None, attempt=attempt)
        ap.live.clear()
        for h in self.hosts_of.pop(ap.program_id, ()):  # the indexes serve live programs only
            self.by_host.get(h, {}).pop(ap.program_id, None)
            self.offered.get(h, {}).pop(ap.program_id, None)
        ap.state = S.DONE if ok else S.FAILED
        ap.deadline = None
        self._finished.append((now, ap.program_id))
        self.delivered += 1
        ap.moving_from = None
        late = deadlines.late(ap.submit, now, ok=ok, kind=kind)
        if late is not None:
            self.deadline_misses += 1
            out.append(Note(what="deadline_missed", program_id=ap.program_id, robot=host, attempt=ap.attempt,
                            detail=late))
        out.append(Deliver(program_id=ap.program_id, ok=ok, value=value, error=error, error_kind=kind, host=host,
                           attempts=ap.made, moves=ap.moves, resumed_from=ap.resumed_from,
                           missed_deadline=late is not None))

    def leave_host(self, ap: AutonomousProgram, host: str | None, finish_seq: int | None,
                   *, attempt: int | None = None) -> None:
        """The view's booking of ``ap``'s attempt (the current one by default) on ``host`` ends."""
        if host is None:
            return
        self.view.released(host, ap.program_id, ap.attempt if attempt is None else attempt, finish_seq)

    # ================================================================ relocation
    def _relocating(self) -> bool:
        return self.config.relocate and any(p.relocates for p in self._policies.values())

    def _relocation_check(self, now: float, out: list[Action]) -> bool:
        return relocation_check(self, now, out)

    def policy_for(self, sub: Submit) -> Policy:
        """The policy that places ``sub``: the one it asked for, else this robot's."""
        return self._policies[sub.policy] if sub.policy else self.policy

    def relocate(self, ap: AutonomousProgram, placement: Placement, now: float, out: list[Action]) -> None:
        """Move ``ap`` where ``placement`` says (``ramps.core.relocation`` found
        it worth it): the ``relocate`` event of its state machine."""
        self._step(ap, E.RELOCATE, now, out, placement)

    def active(self) -> int:
        return sum(1 for ap in self.programs.values() if ap.state not in FINAL)


#: the table's handlers, resolved once: a misspelt name fails here, at import
_HANDLERS = resolve_handlers(Origin, TRANSITIONS)
