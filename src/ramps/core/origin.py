"""The origin side of the protocol: every autonomous program this robot owns.

How this works: ``Origin`` keeps the robot's autonomous programs, their
timers (connect timeout, heartbeat timeout, back-off) in one heap, and an
index of programs by host. Each input is turned into a program event and
dispatched through ``ramps.core.program.TRANSITIONS``; handlers return
actions into the list they are given. Results are delivered exactly once:
a program keeps the set of attempts whose results it still wants (``live``);
anything else is acknowledged, so the host stops resending, and discarded.

Relocation after placement: ``ramps.core.relocation`` decides when a running
program should move and where (eq. (1) with its thresholds); the move
itself is a transition here: ``MOVING`` keeps the old copy running until
the new host accepts, a result from either copy is delivered and the other
stopped, and a refusal or failure of the new host leaves the old copy
running.

Deadlines: a program may carry one (``Submit.deadline``, absolute in the core's time, a finite number).
The policy keeps to hosts expected to finish in time; when none is (``Placement.late``), or the deadline
has passed at a re-placement, its ``on_miss`` decides: "run" where it ends soonest, "local" here, or
"fail" at once (``error_kind`` "deadline"). Offered in time, placed or moved, a program tells its host
how long it has (``OffloadRequest.deadline_in``); the host turns it away as "late" if it or a program it
runs would miss (then it is placed at once elsewhere, or stays where it runs); one run anyway is offered
without it. Delivered after its deadline, it is a miss (``Deliver.missed_deadline``, ``deadline_misses``).

Rules: no clock (``now`` comes in), no I/O, randomness from the injected
``rng``. Remote misbehaviour (a message about a program we never had, an
illegal transition caused by a peer) is counted in ``anomalies`` and never
raises.

Over 500 lines for a reason: the handlers are the transitions of one state
machine and share its program index, timer heap and exactly-once
bookkeeping; relocation's decision already lives apart. Splitting the
handlers further would put one table's transitions in several files.
"""

from __future__ import annotations

import heapq
import math
import random
import sys
from collections import deque
from typing import Any

import msgspec

from ramps.core.config import RampsConfig
from ramps.core.cost import NetworkEstimate
from ramps.core.durable import RESTORE_GRACE
from ramps.core.events import Action, Deliver, Note, Progress, Send, Submit
from ramps.core.learning import Learning
from ramps.core.links import Links
from ramps.core.loadview import LoadView
from ramps.core.messages import (
    CancelProgram,
    Heartbeat,
    OffloadAccepted,
    OffloadRejected,
    OffloadRequest,
    ProgramCheckpoint,
    ProgramProgress,
    ProgramResult,
    ResultAck,
)
from ramps.core.policy import Placement, Policy, PlacementRequest, make_policy
from ramps.core.program import (
    FINAL,
    TRANSITIONS,
    AutonomousProgram,
    poison_error,
    poison_pill,
    resolve_handlers,
    Event,
    IllegalTransition,
    ProgramState,
    ProtocolError,
)
from ramps.core.relink import Relink
from ramps.core.relocation import relocation_check

S = ProgramState
E = Event
#: what a program with a deadline may do when no robot is expected to meet
#: it (``Submit.on_miss``): run where it ends soonest, run here, or fail now
ON_MISS = ("run", "local", "fail")


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
        self._by_host: dict[str, dict[str, None]] = {}  # host -> its live program ids, in placement order (a set's order would follow the process's hash seed)
        self._timers: list[tuple[float, int, str]] = []
        #: programs with a recently written-off attempt that an isolation would revive
        self._revivable: dict[str, None] = {}  # ordered, like _by_host
        #: finished programs, oldest first: kept for ``result_retention`` so a
        #: late result is settled (acknowledged, discarded), then forgotten
        self._finished: deque[tuple[float, str]] = deque()
        self._seq = 0
        #: measured latency and bandwidth per teammate (set by the node)
        self.links: Links | None = None
        #: after this robot's own stall, the hosts whose links are not back yet
        self.relink = Relink(me)
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
        self._resumed: dict[str, int] = {}

    # ================================================================ inputs
    def submit(self, sub: Submit, now: float, out: list[Action]) -> None:
        if sub.program_id in self.programs:
            raise ValueError(f"program id {sub.program_id!r} was already submitted")
        if not (math.isfinite(sub.work) and sub.work >= 0):  # NaN work made every policy's choice fail
            raise ValueError(f"program {sub.program_id!r}: work must be finite and >= 0, got {sub.work!r}")
        if sub.on_miss not in ON_MISS:
            raise ValueError(f"program {sub.program_id!r}: on_miss is one of {', '.join(ON_MISS)}, got {sub.on_miss!r}")
        if sub.deadline is not None and not (type(sub.deadline) in (int, float)
                                             and abs(sub.deadline) <= sys.float_info.max):  # not NaN, inf, 10**400
            raise ValueError(f"program {sub.program_id!r}: a deadline must be a finite number, got {sub.deadline!r}")
        if not (math.isfinite(sub.accelerator_work) and sub.accelerator_work >= 0):
            raise ValueError(f"program {sub.program_id!r}: accelerator_work must be finite and >= 0, "
                             f"got {sub.accelerator_work!r}")
        if not sub.accelerator and not sub.cpu_fallback:
            raise ValueError(f"program {sub.program_id!r}: cpu_fallback=False needs an accelerator kind")
        if sub.policy and sub.policy not in self._policies:
            self._policies[sub.policy] = make_policy(sub.policy)  # ValueError names the known ones
        ap = self.programs[sub.program_id] = AutonomousProgram(sub, now)
        self._changed(ap)
        if self.bursts:
            self.held.append(ap)
        else:
            self.place(ap, now, out)

    def restore(self, programs: list[AutonomousProgram], now: float, out: list[Action]) -> None:
        """Resume programs a previous process of this robot owned
        (``ramps.core.durable.program_of``): one whose current attempt ran on
        a teammate waits ``RESTORE_GRACE`` to hear of it there, as if just
        offered; one that ran here or was backing off is placed again now."""
        for ap in programs:
            if ap.program_id in self.programs:
                raise ValueError(f"program id {ap.program_id!r} is already here")
            sub = ap.submit
            if sub.policy and sub.policy not in self._policies:
                try:
                    self._policies[sub.policy] = make_policy(sub.policy)
                except ValueError:  # a policy this version does not have: the node's own places it
                    ap.submit = msgspec.structs.replace(sub, policy="")
            self.programs[ap.program_id] = ap
            for attempt, host in list(ap.live.items()):
                if host == self.me:  # its copy here died with the previous process
                    del ap.live[attempt]
                else:
                    self._by_host.setdefault(host, {})[ap.program_id] = None
            out.append(Note(what="restored", program_id=ap.program_id, robot=ap.host or "", attempt=ap.attempt,
                            detail=f"{len(ap.live)} live cop{'y' if len(ap.live) == 1 else 'ies'}"))
            if ap.host is not None and ap.live.get(ap.attempt) == ap.host:
                # offered there again: a host that has it says yes again, one
                # that never got it (the offer went down with the old process)
                # or lost it (it restarted too) takes it now; the offer goes
                # again when the host's liveliness is heard (the first may
                # precede the link)
                ap.state = S.OFFERED
                ap.last_heard = ap.placed_at = ap.accepted_at = ap.done_at = now
                resume = ap.checkpoint is not None
                ap.work = self.work_estimate(ap.submit) * (1.0 - (ap.checkpoint_fraction if resume else 0.0))
                ap.resumed_from = ap.checkpoint_fraction if resume else None
                self._resumed[ap.program_id] = ap.attempt
                self._offer(ap, now, out)
                self._set_timer(ap, now + RESTORE_GRACE, E.CONNECT_TIMEOUT)
            else:
                ap.state = S.BACKOFF
                self._set_timer(ap, now, E.BACKOFF_DONE)

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

    def on_progress(self, msg: ProgramProgress, now: float, out: list[Action]) -> None:
        """A host says how far a program is: pass it on if the attempt is
        still wanted (advisory: no state changes, stale ones dropped)."""
        ap = self.programs.get(msg.program_id)
        if ap is None or ap.state in FINAL or ap.live.get(msg.attempt) != msg.host:
            return
        if msg.attempt == ap.attempt:
            self._progress_at(ap, msg.fraction, now)
        out.append(Progress(program_id=msg.program_id, host=msg.host, attempt=msg.attempt,
                            fraction=msg.fraction, detail=msg.detail))

    def on_checkpoint(self, msg: ProgramCheckpoint, now: float, out: list[Action]) -> None:
        """A live copy saved its state: keep the latest (a restart after a
        move or a failure resumes from it). Stale ones are dropped."""
        ap = self.programs.get(msg.program_id)
        if ap is None or ap.state in FINAL or ap.live.get(msg.attempt) != msg.host:
            return
        fraction = msg.fraction
        if fraction is not None and ap.checkpoint is not None and fraction < ap.checkpoint_fraction:
            return  # an older copy, behind the state we already hold
        if fraction is None:  # the program says nothing of how far it is: assume the work is all ahead
            fraction = (ap.resumed_from or 0.0) if msg.attempt == ap.attempt else 0.0
        ap.checkpoint = msg.state
        ap.checkpoint_fraction = fraction
        self._changed(ap)
        if msg.attempt == ap.attempt:
            self._progress_at(ap, fraction, now)
        out.append(Note(what="checkpoint", program_id=ap.program_id, robot=msg.host, attempt=msg.attempt,
                        detail=f"{len(msg.state)} bytes at {fraction:.3f}"))

    def _progress_at(self, ap: AutonomousProgram, fraction: float, now: float) -> None:
        """The current attempt says it is ``fraction`` of the whole program
        through: set the origin's estimate of the work it has done."""
        base = ap.resumed_from or 0.0
        if base < 1.0:
            ap.done = min(ap.work, max(0.0, (fraction - base) / (1.0 - base) * ap.work))
            ap.done_at = now

    def on_heartbeat(self, msg: Heartbeat, now: float, out: list[Action]) -> None:
        for ref in msg.programs:
            self._route(ref.program_id, ref.attempt, msg.host, E.HEARTBEAT, now, out, None)

    def on_peer_lost(self, robot: str, now: float, out: list[Action]) -> None:
        self.view.set_lost(robot, True)
        for pid in list(self._by_host.get(robot, ())):
            ap = self.programs[pid]
            old = ap.moving_from
            if ap.state is S.MOVING and old is not None and old[1] == robot:
                # the copy a move is taking over from is gone: the move goes on
                self._drop_old_copy(ap)
                self._changed(ap)
                out.append(Note(what="failed", program_id=pid, robot=robot, attempt=old[0],
                                detail="host_lost while moving away"))
            if ap.host == robot and ap.state in (S.OFFERED, S.RUNNING, S.MOVING):
                self._step(ap, E.HOST_LOST, now, out, None)
        if self.view.isolated(now, self.config.isolation_timeout):
            self._revive_written_off(now, out)

    def _revive_written_off(self, now: float, out: list[Action]) -> None:
        """Every teammate is gone at once: it is this robot that was cut off.
        Teammates lost a moment earlier (their leases ran out one by one, or
        their heartbeats timed out first) were not at fault: want their
        copies' results again, beside the local run; first result wins."""
        horizon = now - self._revive_window()
        for pid in list(self._revivable):
            ap = self.programs.get(pid)
            if ap is None or ap.state in FINAL or not ap.written_off:
                continue
            for attempt, host, when in ap.written_off:
                if when >= horizon and host != self.me and attempt not in ap.live:
                    ap.live[attempt] = host
                    self._changed(ap)
                    out.append(Note(what="isolated", program_id=ap.program_id, robot=host, attempt=attempt,
                                    detail="revived: this robot was cut off, not the host"))
            ap.written_off.clear()
        self._revivable.clear()

    def _revive_window(self) -> float:
        # a host is written off at most a heartbeat timeout after the cut, and
        # the cut is certain at most an isolation timeout after it
        return self.config.heartbeat_timeout + self.config.isolation_timeout + self.config.heartbeat_period

    def on_peer_alive(self, robot: str, now: float, out: list[Action]) -> None:
        self.view.set_lost(robot, False)
        for pid, attempt in list(self._resumed.items()):  # restored offers not answered yet: again
            ap = self.programs.get(pid)
            if ap is None or ap.state is not S.OFFERED or ap.attempt != attempt:
                del self._resumed[pid]
            elif ap.host == robot:
                self._offer(ap, now, out)

    def on_stalled(self, seconds: float, now: float, *, links: bool = False) -> None:
        """This robot's driver did not run for ``seconds`` (taken out of the
        core's clock, so ``now`` is about when it stopped) and woke at ``now``.
        What its hosts sent meanwhile is still on its way in, read by a node
        that runs again at the pace it was starved at: a host's silence counts
        only from the wake plus the stall's length (at most a heartbeat
        timeout), so a stall of this origin's never writes off a healthy host
        (issue 23); and relocation waits ``relocate_calm``. After a stall
        that may have closed links (``links``) ``ramps.core.relink`` waits
        for each host's link instead."""
        seconds = max(0.0, seconds)
        self.stalled_s += seconds
        self.woke_at = now
        self.wake_grace = 0.0 if links else min(seconds, self.config.heartbeat_timeout)

    # ================================================================ timers
    def next_deadline(self) -> float | None:
        while self._timers:
            when, _, pid = self._timers[0]
            ap = self.programs.get(pid)
            if ap is not None and ap.deadline == when:
                break
            heapq.heappop(self._timers)  # stale entry
        first = self._timers[0][0] if self._timers else None
        if self._relocate_due is not None and len(self.programs) <= len(self._finished):
            self._relocate_due = None  # every program has ended: nothing to move
        if self._relocate_due is not None and (first is None or self._relocate_due < first):
            first = self._relocate_due
        check = self._isolation_check()
        if check is not None and (first is None or check < first):
            return check
        return first

    def _isolation_check(self) -> float | None:
        """When silence from every teammate would reveal that this robot, not
        the hosts it just wrote off, was cut off (see _revive_written_off)."""
        if not self._revivable or self.view.last_remote_report is None:
            return None
        return self.view.last_remote_report + self.config.isolation_timeout + 1e-6

    def tick(self, now: float, out: list[Action]) -> None:
        if self._revivable:
            if self.view.isolated(now, self.config.isolation_timeout):
                self._revive_written_off(now, out)
            else:
                newest = max((w[2] for pid in self._revivable if (ap := self.programs.get(pid)) is not None
                              for w in ap.written_off), default=None)
                if newest is None or newest < now - self._revive_window():
                    self._revivable.clear()  # too old to be explained by an isolation now
        horizon = now - self.config.result_retention
        while self._finished and self._finished[0][0] < horizon:
            _, pid = self._finished.popleft()
            ap = self.programs.get(pid)
            if ap is not None and ap.state in FINAL:
                del self.programs[pid]
        while self._timers and self._timers[0][0] <= now:
            when, _, pid = heapq.heappop(self._timers)
            ap = self.programs.get(pid)
            if ap is None or ap.deadline != when or ap.state in FINAL:
                continue
            ap.deadline = None
            kind = ap.timer
            if self.relink.waiting(ap.host, now) and kind in (E.HEARTBEAT_TIMEOUT, E.CONNECT_TIMEOUT):
                self._set_timer(ap, self.relink.until, kind)  # its link is not back since this robot stalled
                continue
            heard_from = self.woke_at + self.wake_grace  # after this robot's stall (on_stalled)
            if kind == E.CONNECT_TIMEOUT and heard_from + self.config.connect_timeout > now:
                # this robot stalled meanwhile: the acceptance may be behind the stall
                self._set_timer(ap, heard_from + self.config.connect_timeout, kind)
                continue
            if kind == E.HEARTBEAT_TIMEOUT:
                # silence counts from the last word of the host, or from this
                # robot's latest stall, whichever is later
                due = max(ap.last_heard, heard_from) + self.config.heartbeat_timeout
                if due > now:  # heard from the host since the timer was set, or this robot stalled
                    self._set_timer(ap, due, kind)
                    continue
            if kind is not None:
                self._step(ap, kind, now, out, None)
        if self._relocate_due is not None and now >= self._relocate_due:
            self._relocate_due = None
            if self._relocation_check(now, out):
                self._relocate_due = now + self.config.relocate_period

    def relinked(self, host: str, now: float) -> None:
        """``host``'s link is back after this robot's stall (``ramps.core.relink``):
        its silence counts from now, for a heartbeat or a connect timeout."""
        for pid in self._by_host.get(host, ()):
            ap = self.programs[pid]
            if ap.host == host and ap.state in (S.OFFERED, S.RUNNING) and ap.deadline is not None:
                ap.last_heard = max(ap.last_heard, now)
                if ap.timer == E.CONNECT_TIMEOUT:
                    self._set_timer(ap, max(ap.deadline, now + self.config.connect_timeout), ap.timer)

    def _set_timer(self, ap: AutonomousProgram, when: float, kind: Event) -> None:
        ap.deadline = when
        ap.timer = kind
        self._seq += 1
        heapq.heappush(self._timers, (when, self._seq, ap.program_id))

    # ================================================================ dispatch
    def _route(self, pid: str, attempt: int, host: str, event: Event, now: float, out: list[Action], msg: Any) -> None:
        ap = self.programs.get(pid)
        if ap is None:
            self._anomaly(out, pid, host, f"{event} for a program this robot never submitted")
            if event == E.RESULT:
                out.append(Send(to=host, msg=ResultAck(program_id=pid, attempt=attempt, origin=self.me)))
            return
        if attempt == ap.attempt and host == ap.host and ap.live.get(attempt) == host:
            # the current attempt, still wanted (not written off while backing off)
            self._step(ap, event, now, out, msg)
            return
        # about an attempt that is not the current one
        if event == E.RESULT:
            out.append(Send(to=host, msg=ResultAck(program_id=pid, attempt=attempt, origin=self.me)))
            if ap.state not in FINAL and ap.live.get(attempt) == host:
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

    # ================================================================ handlers
    def _ignore(self, ap: AutonomousProgram, now: float, out: list[Action], msg: Any, event: Event) -> None:
        pass

    def _place(self, ap: AutonomousProgram, now: float, out: list[Action], msg: Any, event: Event) -> None:
        self.place(ap, now, out)

    def place(self, ap: AutonomousProgram, now: float, out: list[Action], *, host: str | None = None,
              placement: Placement | None = None, prefer: tuple[str, float] = ("", 0.0)) -> None:
        """Offer ``ap``'s next attempt: to ``host``, where a relocation's
        ``placement`` says, or where its policy chooses (``prefer``: the host
        a burst's plan chose for it and the plan's end, ``ramps.core.burst``)."""
        sub = ap.submit
        work = self.work_estimate(sub)
        resume = ap.checkpoint
        fraction = ap.checkpoint_fraction if resume is not None else 0.0
        work *= 1.0 - fraction  # what is left from the checkpoint
        expected = budget = deadline_in = None
        left = sub.deadline - now if sub.deadline is not None else None
        if placement is not None:  # a relocation priced it already (and tells the new host the time left)
            host, expected, budget = placement.host, placement.expected_runnable, placement.time_budget
            deadline_in = left if left is not None and (placement.expected_time or 0.0) < left else None
        if host is None and sub.local_only:
            host = self.me
        accel_work = self.accelerator_work_estimate(sub) * (1.0 - fraction)
        if host is None:
            policy = self.policy_for(sub)
            exclude = self.exclusions(ap, now, out)
            if exclude is None:
                return
            placement = policy.choose(
                self.request(ap, work, accel_work, left, prefer),
                self.view, now, self.rng, net=self.net, config=self.config, exclude=exclude,
                links=self.links.estimate if self.links is not None else None,
            )
            host = placement.host
            if policy.negotiates:
                expected = placement.expected_runnable
                budget = placement.time_budget
            if left is not None and (placement.late or left <= 0.0):
                host = self._deadline_unmet(ap, placement, left, now, out)
                if host is None:
                    return
                if host != placement.host:  # the policy's estimates were for its pick
                    expected = budget = None
            elif left is not None and policy.negotiates:
                deadline_in = left  # the host checks it against its true load
        if ap.host is not None and ap.host not in ap.live.values():
            self._by_host.get(ap.host, {}).pop(ap.program_id, None)
        ap.made += 1
        ap.attempt = ap.made
        ap.host = host
        ap.live[ap.attempt] = host
        ap.state = S.OFFERED
        ap.last_heard = now
        ap.accelerator = sub.accelerator if sub.accelerator in self.view.accelerator_kinds(host) else ""
        if ap.accelerator:
            work = accel_work
        ap.work, ap.done, ap.done_at = work, 0.0, now
        ap.placed_at, ap.stall_base = now, self.stalled_s
        ap.resumed_from = fraction if resume is not None else None
        self._by_host.setdefault(host, {})[ap.program_id] = None
        self.view.book(host, ap.program_id, ap.attempt, ap.accelerator, work, now)
        self.placements += 1
        detail = ""
        if placement is not None and placement.expected_time is not None:  # why there, for traces
            detail = f"expected {placement.expected_time:.2f} s"
            if placement.time_budget is not None:
                detail += f", budget {placement.time_budget:.2f} s"
        out.append(Note(what="placed", program_id=ap.program_id, robot=host, attempt=ap.attempt, detail=detail))
        self._offer(ap, now, out, expected=expected, budget=budget, deadline_in=deadline_in)
        # the host cannot accept before the parameters have crossed the link,
        # behind those of this robot's other offers to it still on their way
        transfer = 0.0
        if host != self.me:
            link = self.links.estimate(host) if self.links is not None else self.net
            queued = sum(self.programs[pid].submit.payload_size for pid in self._by_host.get(host, ())
                         if self.programs[pid].state is S.OFFERED and self.programs[pid].host == host)
            transfer = queued / link.bandwidth
        self._set_timer(ap, now + self.config.connect_timeout + transfer, E.CONNECT_TIMEOUT)

    def request(self, ap: AutonomousProgram, work: float, accel_work: float, left: float | None,
                prefer: tuple[str, float] = ("", 0.0)) -> PlacementRequest:
        """What the policy is asked to place for ``ap`` (``left``: seconds to its deadline)."""
        sub = ap.submit
        return PlacementRequest(program_id=ap.program_id, work=work, deadline=left, prefer=prefer[0], plan_end=prefer[1],
                                payload_size=sub.payload_size + len(ap.checkpoint or b""), result_size=sub.result_size,
                                accelerator=sub.accelerator, accelerator_work=accel_work)

    def exclusions(self, ap: AutonomousProgram, now: float, out: list[Action]) -> frozenset[str] | None:
        """The robots ``ap`` may not go to now; None when there is nowhere
        it may (it then waits or failed, ``_without_accelerator``)."""
        sub = ap.submit
        exclude = (frozenset(ap.excluded) | self.view.short_of_memory(sub.memory) | self.view.low_battery
                   | self.relink.excluded(self.view.robots(), now))
        if sub.accelerator and not sub.cpu_fallback:
            return self._without_accelerator(ap, exclude, now, out)
        return exclude

    def _deadline_unmet(self, ap: AutonomousProgram, placement: Placement, left: float, now: float,
                        out: list[Action]) -> str | None:
        """No candidate is expected to finish ``ap`` within the ``left``
        seconds to its deadline: its ``on_miss`` says where it runs anyway
        (the policy's pick, or this robot), or it fails now (None)."""
        sub = ap.submit
        best = placement.expected_time
        at_best = f"{best:.2f} s at best (on {placement.host})" if best is not None else "too long"
        why = f"expected {at_best}, {max(0.0, left):.2f} s left to its deadline"
        if sub.on_miss == "fail":
            self._deliver(ap, now, out, ok=False, kind="deadline", host=placement.host,
                          error=f"{sub.program} cannot meet its deadline: {why}")
            return None
        host = self.me if sub.on_miss == "local" else placement.host
        out.append(Note(what="deadline_unmet", program_id=ap.program_id, robot=host, attempt=ap.made + 1,
                        detail=f"{why}; on_miss={sub.on_miss}"))
        return host

    def _offer(self, ap: AutonomousProgram, now: float, out: list[Action], *, expected: float | None = None,
               budget: float | None = None, deadline_in: float | None = None) -> None:
        """Send the current attempt's offer (``OffloadRequest``) to its host,
        with its latest checkpoint: what is left of the work from there."""
        sub = ap.submit
        resume = ap.checkpoint
        out.append(Send(to=ap.placed_host, msg=OffloadRequest(
            program_id=ap.program_id, attempt=ap.attempt, origin=self.me, host=ap.placed_host,
            program=sub.program, args=sub.args, payload_size=sub.payload_size, work=ap.work,
            expected_runnable=expected, time_budget=budget, force=ap.rejections >= self.config.max_rejections,
            resume=resume, resume_fraction=ap.checkpoint_fraction if resume is not None else 0.0,
            deadline_in=deadline_in, accelerator=ap.accelerator,
        )))

    def _without_accelerator(self, ap: AutonomousProgram, exclude: frozenset[str], now: float,
                             out: list[Action]) -> frozenset[str] | None:
        """``exclude`` plus every robot without the accelerator ``ap`` needs
        (it may not run on a CPU). None when no candidate has one: the
        program waits for one (a robot that advertised the kind is away) or,
        if no robot of the team ever advertised it, fails at once."""
        kind = ap.submit.accelerator
        robots = self.view.robots()
        having = [r for r in robots if kind in self.view.accelerator_kinds(r)]
        if self.view.accelerator_rows(now, kind, exclude):
            return exclude | frozenset(r for r in robots if r not in having)
        if not having:
            self._deliver(ap, now, out, ok=False, kind="refused",
                          error=f"{ap.submit.program} needs a {kind!r} accelerator and no robot of the team "
                                f"advertises one (start a node with --accelerator {kind}, or let the "
                                f"program run on a CPU)")
            return None
        ap.failures += 1  # each wait counts towards max_attempts
        self._backoff(ap, now, out)
        return None

    def _on_accepted(self, ap: AutonomousProgram, now: float, out: list[Action], msg: Any, event: Event) -> None:
        if isinstance(msg, OffloadAccepted):
            self.view.accepted(ap.placed_host, ap.program_id, ap.attempt, msg.accept_seq)
        ap.state = S.RUNNING
        ap.last_heard = now
        ap.rejections = 0
        ap.excluded.clear()
        ap.accepted_at = ap.done_at = now
        ap.ran_on[ap.placed_host] = None
        out.append(Note(what="accepted", program_id=ap.program_id, robot=ap.placed_host, attempt=ap.attempt))
        self._set_timer(ap, now + self.config.heartbeat_timeout, E.HEARTBEAT_TIMEOUT)
        if self._relocate_due is None and self._relocating():
            self._relocate_due = now + self.config.relocate_period

    def _on_heartbeat(self, ap: AutonomousProgram, now: float, out: list[Action], msg: Any, event: Event) -> None:
        ap.last_heard = now

    def _on_rejected(self, ap: AutonomousProgram, now: float, out: list[Action], msg: OffloadRejected, event: Event) -> None:
        self.rejections += 1
        host = ap.placed_host
        self._leave_host(ap, host, None)
        ap.live.pop(ap.attempt, None)
        out.append(Note(what="rejected", program_id=ap.program_id, robot=host, attempt=ap.attempt,
                        detail=f"{msg.reason}: {msg.detail}"))
        if msg.permanent:
            self._deliver(ap, now, out, ok=False, error=f"{host} refused program {ap.submit.program!r}: {msg.reason}"
                          + (f" ({msg.detail})" if msg.detail else ""), host=host, kind="refused")
            return
        if msg.report is not None and self.view.on_report(msg.report, now, fresh=True):
            out.append(Note(what="unblacklisted", robot=msg.report.robot))
        ap.rejections += 1
        if msg.reason != "busy" or msg.report is None:
            # a busy host sent its true load, which the view now holds: it may
            # still be the best choice (the origin then expects what it has)
            ap.excluded.add(host)
        if host == self.me and msg.reason == "closing":
            # this robot is shutting down: a local_only program (or any, when
            # no teammate is left) would be offered here again at once and
            # turned away forever; wait instead (the driver cancels it)
            self._backoff(ap, now, out)
            return
        if ap.rejections >= 2 and self.config.contention_backoff > 0 and msg.reason != "late":
            # turned away again: several origins are placing on the same few
            # robots at this moment; wait a random moment (doubling) so their
            # prompt reports arrive before this program tries again
            wait = self.rng.uniform(0.0, self.config.contention_backoff * 2 ** (ap.rejections - 2))
            self._wait(ap, now, out, wait, f"{wait:.3f} after {ap.rejections} rejections")
            return
        self.place(ap, now, out)

    def _on_host_failed(self, ap: AutonomousProgram, now: float, out: list[Action], msg: Any, event: Event) -> None:
        host = ap.placed_host
        reason = event
        self.host_failures += 1
        ap.failures += 1
        ap.deadline = None
        out.append(Note(what="failed", program_id=ap.program_id, robot=host, attempt=ap.attempt, detail=reason))
        if self._still_publishing(host, reason, now):
            # the host says it is alive (load reports after we last heard about
            # this program): messages about the program were lost, not the
            # host. Keep its copy wanted and run the program elsewhere too.
            out.append(Note(what="suspected", program_id=ap.program_id, robot=host, attempt=ap.attempt,
                            detail=f"{reason}, but the host still publishes: its copy stays wanted"))
            ap.excluded.add(host)
            self.place(ap, now, out)
            return
        if host != self.me and self.view.isolated(now, self.config.isolation_timeout):
            # we are the ones cut off: keep the remote attempt's result wanted
            # and run the program here meanwhile; first result wins
            out.append(Note(what="isolated", program_id=ap.program_id, robot=host, attempt=ap.attempt))
            self.place(ap, now, out, host=self.me)
            return
        self._leave_host(ap, host, None)
        ap.live.pop(ap.attempt, None)
        if host != self.me and reason in (E.HOST_LOST, E.HEARTBEAT_TIMEOUT):
            ap.written_off.append((ap.attempt, host, now))
            self._revivable[ap.program_id] = None
        else:
            # a host that just went silent is not told: the message could not
            # arrive, and on Zenoh, sending to a cut-off peer can stall this
            # robot's traffic for seconds. If it is alive, its next heartbeat
            # or acceptance gets a cancel (see _route).
            out.append(Send(to=host, msg=CancelProgram(program_id=ap.program_id, attempt=ap.attempt,
                                                       origin=self.me)))
        if self.view.blacklist(host):
            out.append(Note(what="blacklisted", robot=host, program_id=ap.program_id, detail=reason))
        # a host whose session is gone (connection reset, lease expired) is
        # certainly unreachable: its programs need only a short jitter, since
        # hosts' admission and prompt reports keep the origins re-placing at
        # once from piling up; silence (a timeout) keeps the paper's back-off
        self._backoff(ap, now, out, certain=reason == E.HOST_LOST)

    def _still_publishing(self, host: str | None, reason: Event, now: float) -> bool:
        if not self.config.hedge_suspects or host is None or host == self.me or self.view.is_lost(host):
            return False
        window = {E.HEARTBEAT_TIMEOUT: self.config.heartbeat_timeout,
                  E.CONNECT_TIMEOUT: self.config.connect_timeout}.get(reason)
        age = self.view.report_age(host, now)
        # a report that arrived at least a heartbeat period after we last heard
        # about the program (or offered it): the host outlived the silence. A
        # cut or frozen host's last report is older than that.
        return window is not None and age is not None and age < window - self.config.heartbeat_period

    def _backoff(self, ap: AutonomousProgram, now: float, out: list[Action], *, certain: bool = False) -> None:
        if ap.failures >= self.config.max_attempts:
            self._deliver(ap, now, out, ok=False, host=ap.host or "", kind="failed",
                          error=f"gave up after {ap.failures} failed attempts")
            return
        wait = self.rng.uniform(0.0, self.config.backoff_lost_max if certain else self.config.backoff_max)
        self._wait(ap, now, out, wait, f"{wait:.3f}")

    def _wait(self, ap: AutonomousProgram, now: float, out: list[Action], wait: float, detail: str) -> None:
        """Back off for ``wait`` seconds, then place the program again."""
        ap.state = S.BACKOFF
        out.append(Note(what="backoff", program_id=ap.program_id, attempt=ap.attempt, detail=detail))
        self._set_timer(ap, now + wait, E.BACKOFF_DONE)

    def _on_result(self, ap: AutonomousProgram, now: float, out: list[Action], msg: ProgramResult, event: Event) -> None:
        out.append(Send(to=msg.host, msg=ResultAck(program_id=ap.program_id, attempt=msg.attempt, origin=self.me)))
        self._finish_with(ap, msg, now, out)

    def _finish_with(self, ap: AutonomousProgram, msg: ProgramResult, now: float, out: list[Action]) -> None:
        if not msg.ok and msg.retryable:
            # the worker died under the program, not the program's own error
            self._leave_host(ap, msg.host, msg.finish_seq, attempt=msg.attempt)
            ap.live.pop(msg.attempt, None)
            ap.failures += 1
            out.append(Note(what="failed", program_id=ap.program_id, robot=msg.host, attempt=msg.attempt,
                            detail=f"worker lost: {msg.error}"))
            if msg.worker_died:
                ap.deaths.append((msg.attempt, msg.host, msg.error))
            if ap.state is S.MOVING:
                if msg.attempt == ap.attempt:  # the new copy died: the old one runs on
                    self._abandon_move(ap, now, out, f"worker lost on {msg.host}")
                elif ap.moving_from is not None and ap.moving_from[0] == msg.attempt:
                    ap.moving_from = None  # the old copy died: the move goes on
                return
            if ap.live:
                return  # another live attempt may still deliver
            ap.deadline = None
            if poison_pill(ap.deaths):
                self._deliver(ap, now, out, ok=False, host=msg.host, kind="program", error=poison_error(ap.deaths))
                return
            if ap.failures >= self.config.max_attempts:
                self._backoff(ap, now, out)  # delivers the error
                return
            # not a host failure (no blacklist, no back-off): run it elsewhere now
            ap.excluded.add(msg.host)
            self.place(ap, now, out)
            return
        self._leave_host(ap, msg.host, msg.finish_seq, attempt=msg.attempt)
        ap.live.pop(msg.attempt, None)
        if msg.ok and msg.work_done is not None:
            self._learn(ap, msg.attempt, msg.host, msg.work_done, out)
        self._deliver(ap, now, out, ok=msg.ok, value=msg.value, error=msg.error, host=msg.host,
                      kind="" if msg.ok else "program")

    def _on_cancel(self, ap: AutonomousProgram, now: float, out: list[Action], msg: Any, event: Event) -> None:
        self._deliver(ap, now, out, ok=False, error="cancelled by the application", host=ap.host or "",
                      kind="cancelled")

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

    def _relocate(self, ap: AutonomousProgram, now: float, out: list[Action], msg: Placement, event: Event) -> None:
        """Offer the program to its new host; the old copy runs on meanwhile."""
        old = [ap.attempt, ap.host, ap.last_heard, ap.done, ap.done_at, ap.work, ap.resumed_from, ap.accepted_at,
               ap.placed_at, ap.stall_base]
        ap.moves += 1
        self.moves += 1
        ap.move_wanted_since = None
        ap.moving_from = old
        out.append(Note(what="moving", program_id=ap.program_id, robot=msg.host, attempt=ap.attempt,
                        detail=f"from {ap.host}: expected {msg.expected_time:.1f} s there"))
        self.place(ap, now, out, placement=msg)
        ap.state = S.MOVING

    def _on_moved(self, ap: AutonomousProgram, now: float, out: list[Action], msg: Any, event: Event) -> None:
        """The new host took the program: stop the old copy."""
        self._drop_old_copy(ap, out)
        self._on_accepted(ap, now, out, msg, event)
        out.append(Note(what="moved", program_id=ap.program_id, robot=ap.placed_host, attempt=ap.attempt,
                        detail="" if ap.resumed_from is None else f"resumed from {ap.resumed_from:.3f}"))

    def _drop_old_copy(self, ap: AutonomousProgram, out: list[Action] | None = None) -> None:
        """The copy a move takes over from is no longer wanted (``out``: tell
        its host to stop it) or is gone with its host (``out`` None)."""
        old, ap.moving_from = ap.moving_from, None
        if old is None or ap.live.get(old[0]) != old[1]:
            return
        attempt, host = old[0], old[1]
        ap.live.pop(attempt, None)
        self._leave_host(ap, host, None, attempt=attempt)
        if out is not None:
            out.append(Send(to=host, msg=CancelProgram(program_id=ap.program_id, attempt=attempt, origin=self.me)))
        if host not in ap.live.values():
            self._by_host.get(host, {}).pop(ap.program_id, None)

    def _on_move_failed(self, ap: AutonomousProgram, now: float, out: list[Action], msg: Any, event: Event) -> None:
        host = ap.placed_host
        if event == E.REJECTED:
            self.rejections += 1
            if msg.report is not None and self.view.on_report(msg.report, now, fresh=True):
                out.append(Note(what="unblacklisted", robot=msg.report.robot))
            if msg.permanent:
                ap.moves = self.config.relocate_max_moves  # that host never will; nor try others
            why = f"{host} refused: {msg.reason}"
        else:
            self.host_failures += 1
            if event == E.CONNECT_TIMEOUT:
                out.append(Send(to=host, msg=CancelProgram(program_id=ap.program_id, attempt=ap.attempt,
                                                           origin=self.me)))
            if self.view.blacklist(host):
                out.append(Note(what="blacklisted", robot=host, program_id=ap.program_id, detail=event))
            why = f"{host}: {event}"
        self._abandon_move(ap, now, out, why)

    def _abandon_move(self, ap: AutonomousProgram, now: float, out: list[Action], why: str) -> None:
        """The new copy will not run: go back to the old one, or, if that is
        gone too, place the program again after a short back-off."""
        self.moves_aborted += 1
        host, attempt = ap.host, ap.attempt
        self._leave_host(ap, host, None)
        ap.live.pop(attempt, None)
        if host not in ap.live.values():
            self._by_host.get(host or "", {}).pop(ap.program_id, None)
        old, ap.moving_from = ap.moving_from, None
        out.append(Note(what="move_aborted", program_id=ap.program_id, robot=host or "", attempt=attempt,
                        detail=why))
        ap.deadline = None
        if old is not None and ap.live.get(old[0]) == old[1]:
            (ap.attempt, ap.host, ap.last_heard, ap.done, ap.done_at, ap.work, ap.resumed_from,
             ap.accepted_at, ap.placed_at, ap.stall_base) = old
            ap.state = S.RUNNING
            self._set_timer(ap, max(now, ap.last_heard + self.config.heartbeat_timeout), E.HEARTBEAT_TIMEOUT)
            return
        ap.failures += 1
        self._backoff(ap, now, out, certain=True)

    # ================================================================ helpers
    def _deliver(self, ap: AutonomousProgram, now: float, out: list[Action], *, ok: bool,
                 value: bytes = b"", error: str = "", host: str = "", kind: str = "") -> None:
        for attempt, h in ap.live.items():  # stop every other copy
            out.append(Send(to=h, msg=CancelProgram(program_id=ap.program_id, attempt=attempt, origin=self.me)))
            self._leave_host(ap, h, None, attempt=attempt)
        ap.live.clear()
        for ids in self._by_host.values():  # the index only serves live programs
            ids.pop(ap.program_id, None)
        ap.state = S.DONE if ok else S.FAILED
        ap.deadline = None
        self._finished.append((now, ap.program_id))
        self.delivered += 1
        ap.moving_from = None
        due = ap.submit.deadline
        missed = due is not None and (kind == "deadline" or (ok and now > due))
        if due is not None and missed:
            self.deadline_misses += 1
            out.append(Note(what="deadline_missed", program_id=ap.program_id, robot=host, attempt=ap.attempt,
                            detail="unmeetable" if kind == "deadline" else f"{now - due:.3f} s late"))
        out.append(Deliver(program_id=ap.program_id, ok=ok, value=value, error=error, error_kind=kind, host=host,
                           attempts=ap.made, moves=ap.moves, resumed_from=ap.resumed_from, missed_deadline=missed))

    def _leave_host(self, ap: AutonomousProgram, host: str | None, finish_seq: int | None,
                    *, attempt: int | None = None) -> None:
        if host is None:
            return
        self.view.released(host, ap.program_id, ap.attempt if attempt is None else attempt, finish_seq)

    def active(self) -> int:
        return sum(1 for ap in self.programs.values() if ap.state not in FINAL)


#: the table's handlers, resolved once: a misspelt name fails here, at import
_HANDLERS = resolve_handlers(Origin, TRANSITIONS)
