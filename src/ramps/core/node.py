"""One robot's ramps node, as pure logic: load server + origin + executor.

How this works: ``Node.handle(event, now)`` routes an event to the part that
owns it and returns the actions the driver must carry out; ``tick(now)``
fires due timers and ``next_deadline()`` says when to call it next. A message
a robot sends to itself (a program it placed locally, that program's
heartbeats and result) never leaves the node: it is handed straight back in,
so running locally is just another placement and needs no special path.

``make_report`` builds this robot's ``LoadReport`` from what the driver
measured (CPU, run queue) and what the executor knows (programs running,
accepted and finished counts). Drivers publish it to every teammate and
feed it to this node too, as the paper's local load server hears the local
load publisher. The driver reads the robot's battery before each report
(``BatteryMeasured``): below its reserve it hands back its teammates'
programs and takes no more (``ramps.core.battery``).

Prompt reports (policies that share load, ``Policy.shares_load``): several
origins deciding at once on reports up to a period old pile onto the same
hosts. So when the programs running here change (one accepted, one
finished), the node publishes a report of that instant at once
(``PublishReport``), at most one per ``prompt_report_interval``, and its own
view of itself is updated at once: an origin always knows exactly what its
own robot runs. A driver may set ``prompt_hold``: the changes that follow
the first within it go in one report, made when it is over, and a robot
that places nothing takes in only the reports it publishes. This is the
paper's cNAMP (origins learn each other's bookings) done by the host, which is the one robot that knows them all.

Bursts (``bursts``): programs submitted in one batch of the driver's events
wait for its end (``flush``, or the next ``tick``) and for the claims of the
teammates' bursts before it (``ramps.core.claims``: teammates learn that an
application submits here from ``ApplicationHere`` or the first ``Submit``),
then go together (``ramps.core.burst``).

A load report under this robot's own name from another incarnation is no
teammate's: ``ramps.core.identity`` tells whether a second node runs under
this name, and which of the two leaves (``NameTaken``).
"""

from __future__ import annotations

import random
from collections import deque
from collections.abc import Sequence
from typing import Any

from ramps.core import silence
from ramps.core.accelerators import Accelerator
from ramps.core.battery import BatteryMeasured, Reserve, sane_power
from ramps.core.claims import Claims
from ramps.core.config import RampsConfig
from ramps.core.cost import NetworkEstimate
from ramps.core.events import (
    Action,
    ApplicationHere,
    Cancel,
    CheckpointSaved,
    Event,
    Note,
    OfferSending,
    PeerAlive,
    PeerLost,
    ProgramFinished,
    ProgressReported,
    PublishReport,
    Received,
    Send,
    Submit,
)
from ramps.core.executor import Executor
from ramps.core.identity import SameName
from ramps.core.links import Links, probe_budget
from ramps.core.loadview import LoadView, report_problem
from ramps.core.node_accelerators import accelerators_seen
from ramps.core.oneway import OneWay
from ramps.core.messages import (
    AcceleratorSeen,
    BurstClaim,
    CancelProgram,
    Heartbeat,
    LinkProbe,
    LinkProbeReply,
    LoadReport,
    OffloadAccepted,
    OffloadRejected,
    OffloadRequest,
    ProgramCheckpoint,
    ProgramProgress,
    ProgramResult,
    ResultAck,
)
from ramps.core.origin import Origin
from ramps.core.policy import Policy, make_policy
from ramps.core.program import FINAL
from ramps.core.relink import Stalled
from ramps.core.speed import HostSpeeds, SpeedClass, SpeedEstimate, SpeedMeasured, speed_moved
from ramps.core.statistics import NodeStatistics


class Node:
    def __init__(
        self,
        robot: str,
        *,
        cores: int,
        speed: float,
        policy: Policy | str = "ramps",
        config: RampsConfig | None = None,
        rng: random.Random,
        incarnation: int = 0,
        registry: frozenset[str] | None = None,
        net: NetworkEstimate | None = None,
        program_weight: float = 1.0,
        core_fraction: float = 1.0,
        accelerators: Sequence[Accelerator] = (),
        bursts: bool = False,
        speed_class: str = "",
        submits: bool = False,
    ) -> None:
        self.robot = robot
        self.cores = cores
        self.speed = speed
        #: scheduler weight of this robot's programs against its own software
        #: (``cost.nice_weight(worker_nice)`` on a real robot; 1 = equal sharing)
        self.program_weight = program_weight
        self.incarnation = incarnation
        #: reports under this robot's name from other incarnations (``ramps.core.identity``)
        self.same_name = SameName(incarnation)
        self.config = config or RampsConfig()
        if not isinstance(rng, random.Random):
            # no silent default: two robots seeded alike back off in step
            raise TypeError(f"Node {robot!r}: rng must be a seeded random.Random "
                            f"(e.g. random.Random(seed)), got {type(rng).__name__}")
        self.rng = rng
        self.policy = make_policy(policy) if isinstance(policy, str) else policy
        self.view = LoadView(robot, cores=cores, speed=speed, max_report_age=self.config.max_report_age,
                             program_weight=program_weight)
        self.origin = Origin(robot, self.view, self.policy, self.config, self.rng, net or NetworkEstimate())
        #: programs submitted in one batch of events are placed together at its
        #: end (``flush``, or the next ``tick``): ``ramps.core.burst``
        self.origin.bursts = bursts
        #: T_comm per teammate, measured by link probes (``probe_period``)
        self.links, self.oneway = Links(net or NetworkEstimate()), OneWay(robot)  # oneway: split sessions
        if self.config.probe_period > 0:
            self.origin.links = self.links
        self._probe_due: float | None = 0.0 if self.config.probe_period > 0 else None
        self.executor = Executor(robot, config=self.config, registry=registry, incarnation=incarnation,
                                 cores=cores, speed=speed, program_weight=program_weight,
                                 core_fraction=core_fraction, accelerators=accelerators)
        #: an application submits here (from its first Submit; told in reports of the instant); the bursts' claims
        self.submits, self.claims = submits, Claims(self.executor)
        #: the latest time the driver passed in (reports estimate the work
        #: left in running programs as of then)
        self._now = 0.0
        #: what the driver last measured of each accelerator kind: (memory
        #: total, memory free, utilisation or None), for the load reports
        self.accelerator_measured: dict[str, tuple[int, int, float | None]] = {}
        self.view.accelerators = self._accelerators_seen()
        #: this robot's speed (re-measured) and its teammates' as their results
        #: show (policies that share load only; ``ramps.core.speed``)
        self.own_speed = SpeedEstimate(speed, self.config) if self.policy.shares_load else None
        #: robots of this robot's hardware class and their own figures (a speed it measures itself only)
        self.speed_class = SpeedClass(speed_class if self.own_speed is not None else "", robot)
        self.core_fraction = core_fraction
        self.host_speeds = HostSpeeds(self.config) if self.policy.shares_load else None
        if self.host_speeds is not None:
            self.view.speed_factor = self.host_speeds.factor
        self._report_seq = 0
        #: free memory and the node's own CPU the driver last measured (reports of the instant repeat them)
        self._mem_free = 0
        self._node_cpu = 0.0
        #: prompt reports: (accepted, finished) counts last published, the time of the last
        #: one, when the next one is due, and the seconds one waits for the changes that follow it
        self._prompt = self.policy.shares_load and self.config.prompt_reports
        self._published = (-1, -1) if submits else (0, 0)  # a submitter tells it at once
        self._prompted_at, self.prompt_hold = -float("inf"), 0.0  # no hold: each change at once
        self._prompt_due: float | None = None
        #: this robot's battery: below its reserve or not, and the watts a busy core draws (None: not known)
        self.reserve = Reserve(self.config.battery_reserve, self.config.battery_hysteresis)
        self.power: float | None = None

    # ------------------------------------------------------------ driving
    def handle(self, event: Event, now: float) -> list[Action]:
        self._now = now
        out: list[Action] = []
        self._dispatch(event, now, out)
        return self._prompt_report(self._loopback(out, now), now)

    def handle_all(self, events: Sequence[Event], now: float) -> list[Action]:
        """Events of one instant, in order (a driver's batch of messages):
        ``handle`` of each, with one report of the instant after them all."""
        self._now = now
        out: list[Action] = []
        for event in events:
            self._dispatch(event, now, out)
        return self._prompt_report(self._loopback(out, now), now)

    def tick(self, now: float, *, origin: bool = True) -> list[Action]:
        """Fire due timers. ``origin=False``: only what this robot owes its
        teammates (its programs' heartbeats, prompt reports), not the origin's
        timeouts nor link probes: the driver still has messages queued, maybe
        the very heartbeats those timeouts wait for (issue 23)."""
        # the executor first: the heartbeats of programs running here reach
        # this robot's origin before it checks for silent hosts, so a node
        # that was stalled (busy robot, GC pause, SIGSTOP) does not write off
        # its own programs (issue 14)
        self._now = now
        out: list[Action] = []
        self.executor.tick(now, out)
        if self.origin.held:  # the batch the programs came in is over, or its claims' wait
            self.claims.flush(self.origin, now, out)
        out = self._loopback(out, now)
        if not origin:
            return self._prompt_report(out, now)
        more: list[Action] = []
        self.origin.tick(now, more)
        out.extend(self._loopback(more, now))
        if self._probe_due is not None and now >= self._probe_due:
            candidates = self.view.candidates(now)
            most, refresh = probe_budget(self.config, len(candidates) - 1, self.submits)
            out.extend(self.links.probes(candidates, self.robot, now, most, refresh))
            self._probe_due = now + self.config.probe_period
            out.extend(self.oneway.check(self.view, now, self.submits and not self.config.report_fanout))
        return self._prompt_report(out, now)

    def flush(self, now: float) -> list[Action]:
        """The driver's batch of events is over: place the programs submitted
        in it, together (``ramps.core.burst``; nothing without ``bursts``)."""
        if not self.origin.held:
            return []
        self._now = now
        out: list[Action] = []
        self.claims.flush(self.origin, now, out)
        return self._prompt_report(self._loopback(out, now), now)

    def next_deadline(self) -> float | None:
        if self.origin.held:  # at once (the end of their batch, ``flush``), or the claims' wait
            return self.claims.due(self.origin.held[0].submitted_at)
        first = self.origin.next_deadline()  # the driver asks twice a round: no list built
        for t in (self.executor.next_deadline(), self._prompt_due, self._probe_due):
            if t is not None and (first is None or t < first):
                first = t
        return first

    def _prompt_report(self, out: list[Action], now: float) -> list[Action]:
        """Publish a report of this instant when the programs running here
        changed (see the module docstring)."""
        if not self._prompt:
            return out
        counts = (self.executor.accepted_total, self.executor.finished_total)
        if counts == self._published:
            self._prompt_due = None
            return out
        due = self._prompted_at + self.config.prompt_report_interval
        if self.prompt_hold > 0.0:  # the first change not published yet is due a hold later
            due = max(due, now + self.prompt_hold if self._prompt_due is None else self._prompt_due)
        if now < due:  # this robot's own view is exact at once; the team hears at ``due``
            if self.submits or self.prompt_hold <= 0.0:
                self.view.on_report(self.current_report(), now, fresh=True)
            self._prompt_due = due
            return out
        self._published, self._prompted_at, self._prompt_due = counts, now, None
        self._report_seq += 1
        report = self.current_report(with_class=True)
        self.view.on_report(report, now)
        out.append(PublishReport(report=report))
        return out

    def _loopback(self, out: list[Action], now: float) -> list[Action]:
        """Hand messages addressed to this robot straight back in."""
        if not out or not any(isinstance(a, Send) and a.to == self.robot for a in out):
            return out
        result: list[Action] = []
        queue = deque(out)
        while queue:
            action = queue.popleft()
            if isinstance(action, Send) and action.to == self.robot:
                more: list[Action] = []
                self._dispatch(Received(sender=self.robot, msg=action.msg), now, more)
                queue.extend(more)
            else:
                result.append(action)
        return result

    def _dispatch(self, event: Event, now: float, out: list[Action]) -> None:
        if isinstance(event, Received):
            self._receive(event.sender, event.msg, now, out, event.at)
        elif isinstance(event, (Submit, ApplicationHere)):
            if not self.submits:  # an application submits here: teammates hear it now (ramps.core.claims)
                self.submits, self._published = True, (-1, -1)
                if self.prompt_hold > 0.0:  # it places from an exact view of itself
                    self.view.on_report(self.current_report(), now, fresh=True)
            if isinstance(event, Submit):
                self.origin.submit(event, now, out)
        elif isinstance(event, ProgramFinished):
            self.executor.on_finished(event, now, out)
        elif isinstance(event, ProgressReported):
            self.executor.on_progress(event, now, out)
        elif isinstance(event, CheckpointSaved):
            self.executor.on_checkpoint(event, now, out)
        elif isinstance(event, Cancel):
            self.origin.cancel(event.program_id, now, out)
        elif isinstance(event, SpeedMeasured):
            if self.own_speed is not None and self.own_speed.measured_event(event):
                self._published = (-1, -1)  # its class hears its own figure now (a report of the instant)
                self._go_by_speed(now, out, "measured again while idle")
        elif isinstance(event, PeerLost):
            if event.robot != self.robot:
                self.oneway.peer_lost(event.robot, now)
                self.executor.on_origin_lost(event.robot, now)  # its programs here: stopped if it stays away
                if self.speed_class.forget(event.robot):
                    self._go_by_speed(now, out, f"{event.robot} left its class")
                self.origin.on_peer_lost(event.robot, now, out)
        elif isinstance(event, PeerAlive):
            self.oneway.peer_alive(event.robot, now)
            if event.robot != self.robot:
                self._published = (-1, -1)  # a teammate (new, or back) hears this robot's load now, not next period
            self.executor.on_origin_back(event.robot)
            self.origin.on_peer_alive(event.robot, now, out)
            if self.origin.relink.heard(event.robot, now, certain=True):
                self.origin.relinked(event.robot, now)
                out.append(Note(what="relinked", robot=event.robot, detail="its link is back after this robot's stall"))
        elif isinstance(event, Stalled):  # this robot's links may be down for a while (ramps.core.relink)
            self.origin.on_stalled(event.seconds, now, links=event.links)
            if not event.links:
                return
            self.origin.relink.stalled(now)
            out.append(Note(what="relinking", robot=self.robot, detail=f"stalled {event.seconds:.3f} s: teammates' "
                            f"silence counts once their links are back (at most {self.origin.relink.timeout} s)"))
        elif isinstance(event, BatteryMeasured):
            self._battery(event, now, out)
        elif isinstance(event, OfferSending):
            silence.sending(self.origin, event.program_id, event.attempt, event.done, now)
        else:
            raise TypeError(f"not a ramps event: {event!r}")

    def _battery(self, ev: BatteryMeasured, now: float, out: list[Action]) -> None:
        """The driver read this robot's battery: below its reserve, hand back
        the teammates' programs running here and take no more; above it
        again (with the hysteresis), take them again (``ramps.core.battery``)."""
        self.power = sane_power(ev.power)
        if not self.reserve.update(ev.charge):
            return
        r = self.reserve
        self.executor.low_battery = r.low
        charge = "none" if r.charge is None else f"{r.charge:.0%}"
        if r.low:
            why = f"{self.robot} is below its battery reserve ({charge} < {r.reserve:.0%}): handed back"
            handed = self.executor.hand_back(now, out, why=why)
            out.append(Note(what="battery_low", robot=self.robot, detail=f"charge {charge}, reserve {r.reserve:.0%}: "
                            f"{handed} teammates' programs handed back, none taken until {min(1.0, r.reserve + r.hysteresis):.0%}"))
        else:
            out.append(Note(what="battery_ok", robot=self.robot, detail=f"charge {charge}: takes teammates' programs again"))

    def _go_by_speed(self, now: float, out: list[Action], why: str) -> None:
        """Go by this robot's own figure, or its class's (``SpeedClass.rate``), if that moved."""
        assert self.own_speed is not None
        own = self.own_speed.value
        rate, robots = self.speed_class.rate(self._cpu_rate() or 0.0, self.own_speed.se)
        speed = round(rate * self.core_fraction, 6)
        if not speed_moved(speed, self.speed):
            return
        pooled = f" (its own {own:.4g}, the median of {robots} robots of its class)" if robots > 1 else ""
        out.append(Note(what="speed", robot=self.robot, detail=f"{self.speed:.4g} -> {speed:.4g}: {why}{pooled}"))
        self.executor.set_speed(speed, now)
        self.speed = self.view.speed = speed

    def _receive(self, sender: str, msg: object, now: float, out: list[Action], at: float | None = None) -> None:
        if isinstance(msg, LoadReport) and msg.robot == self.robot and msg.incarnation != self.incarnation:
            taken = self.same_name.heard(msg, now)  # another node under this name, or this one's previous process
            if taken is not None:
                out.append(taken)
            return
        arrived = now if at is None else min(at, now)
        if type(msg) is not LoadReport:  # reports are in the view (``ramps.core.liveness``)
            self.origin.heard[sender] = arrived
        if self.origin.relink.active(now) and self.origin.relink.heard(sender, now):
            self.origin.relinked(sender, now)
            out.append(Note(what="relinked", robot=sender, detail="heard again after this robot's stall"))
        if isinstance(msg, LoadReport):
            problem = report_problem(msg)
            if problem is not None:
                self.origin.anomalies += 1
                out.append(Note(what="anomaly", robot=sender, detail=problem))
            else:
                if self.host_speeds is not None and self.host_speeds.on_reported_speed(msg.robot, msg.speed):
                    out.append(Note(what="speed", robot=msg.robot, detail=f"measured itself again ({msg.speed:.4g}): "
                                                                          f"its results' correction starts over"))
                if self.view.on_checked_report(msg, now):
                    out.append(Note(what="unblacklisted", robot=msg.robot))
                if self.speed_class.heard(msg.robot, msg.speed_class, msg.cpu_rate):
                    self._go_by_speed(now, out, f"{msg.robot} measured itself")
                if msg.submits:
                    self.claims.submitters.add(msg.robot)
        elif isinstance(msg, BurstClaim):
            self.claims.on_claim(self.origin, sender, msg, now, out)
        elif isinstance(msg, OffloadRequest):
            self.executor.on_offload(msg, now, out, report_now=self.current_report)
        elif isinstance(msg, OffloadAccepted):
            self.origin.on_accepted(msg, now, out)
        elif isinstance(msg, OffloadRejected):
            self.origin.on_rejected(msg, now, out)
        elif isinstance(msg, Heartbeat):
            self.origin.on_heartbeat(msg, now, out, heard=arrived)
        elif isinstance(msg, ProgramResult):
            if self.host_speeds is not None:
                self._compare_speed(msg, now, out)
            self.origin.on_result(msg, now, out)
        elif isinstance(msg, ResultAck):
            self.executor.on_ack(msg)
        elif isinstance(msg, ProgramProgress):
            self.origin.on_progress(msg, now, out)
        elif isinstance(msg, ProgramCheckpoint):
            self.origin.on_checkpoint(msg, now, out)
        elif isinstance(msg, LinkProbe):
            out.append(Send(to=sender, msg=LinkProbeReply(sent_at=msg.sent_at, size=len(msg.padding))))
        elif isinstance(msg, LinkProbeReply):
            self.links.on_reply(sender, msg, now)
        elif isinstance(msg, CancelProgram):
            self.executor.on_cancel(msg, now, out)
        else:
            self.origin.anomalies += 1
            out.append(Note(what="anomaly", robot=sender, detail=f"unexpected message {type(msg).__name__}"))

    # ------------------------------------------------------------ load publisher
    def make_report(self, *, cpu_busy: float, runnable: float, ramps_avg: float, window: float,
                    mem_free: int = 0, cpu_per_core: list[float] | None = None, load_avg: float = 0.0,
                    node_cpu: float = 0.0) -> LoadReport:
        """This robot's load report, from the driver's measurements."""
        self._report_seq += 1
        self._mem_free, self._node_cpu = mem_free, node_cpu
        return self._report(cpu_busy=cpu_busy, runnable=runnable, ramps_avg=ramps_avg, window=window,
                            mem_free=mem_free, cpu_per_core=cpu_per_core or [], load_avg=load_avg,
                            blacklisted=self.view.blacklisted(), node_cpu=node_cpu)

    def _compare_speed(self, msg: ProgramResult, now: float, out: list[Action]) -> None:
        """The first wanted result of a whole run (not resumed, not moved):
        how fast its host really was, next to the same program elsewhere."""
        ap = self.origin.programs.get(msg.program_id)
        if (ap is None or ap.state in FINAL or ap.live.get(msg.attempt) != msg.host or not msg.ok
                or msg.work_done is None or ap.accelerator):  # a run on an accelerator says nothing of the CPU
            return
        assert self.host_speeds is not None
        before = self.host_speeds.factor.get(msg.host, 1.0)
        if self.host_speeds.on_result(ap.submit.program, msg.host, msg.work_done, ap.submit.work,
                                      started=ap.placed_at, now=now):
            out.append(Note(what="speed", program_id=msg.program_id, robot=msg.host, attempt=msg.attempt,
                            detail=f"runs at {self.host_speeds.factor[msg.host]:.3g} of the speed it reports "
                                   f"(was {before:.3g}): {ap.submit.program} took {msg.work_done:.4g} units "
                                   f"there, less or more elsewhere"))

    def current_report(self, *, with_class: bool = False) -> LoadReport:
        """A report of this instant (sent with a 'busy' rejection); it keeps
        the last sequence number, see ``LoadView.on_report(fresh=True)``.
        ``with_class``: with this robot's speed class and own figure, which
        go only to teammates' nodes of this protocol (``PublishReport``): a
        release that decodes strictly (0.1.0) would drop the whole report."""
        running = self.executor.cpu_programs()
        bg = self.executor.background
        extra: dict[str, Any] = {}
        if with_class and self.speed_class.name:
            extra.update(speed_class=self.speed_class.name, cpu_rate=self._cpu_rate())
        if with_class and self.submits:
            extra["submits"] = True
        return self._report(cpu_busy=min(float(self.cores), bg + running), runnable=bg + running,
                            ramps_avg=float(running), window=0.0, mem_free=self._mem_free, node_cpu=self._node_cpu,
                            **extra)

    def _report(self, **measured: Any) -> LoadReport:
        """A report of this robot: its identity and the executor's counters,
        plus what was ``measured``."""
        return LoadReport(
            robot=self.robot, incarnation=self.incarnation, seq=self._report_seq, cores=self.cores,
            speed=self.speed, program_weight=self.program_weight, ramps_running=self.executor.cpu_programs(),
            accepted_total=self.executor.accepted_total, finished_total=self.executor.finished_total,
            remaining=self.executor.remaining(self._now), moves=self.origin.moves,
            battery=self.reserve.charge, low_battery=self.reserve.low, power=self.power,
            moves_aborted=self.origin.moves_aborted, accelerators=self._accelerators_seen(), **measured,
        )

    def _cpu_rate(self) -> float | None:
        """This robot's own work units per CPU second, for its class."""
        if self.own_speed is None or self.core_fraction <= 0:
            return None
        return round(self.own_speed.value / self.core_fraction, 6)

    def _accelerators_seen(self) -> list[AcceleratorSeen]:
        """This robot's accelerators as its reports list them."""
        return accelerators_seen(self.executor, self.accelerator_measured, self._now)

    def statistics(self) -> NodeStatistics:
        o, e = self.origin, self.executor
        return NodeStatistics(
            robot=self.robot, placements=o.placements, delivered=o.delivered, discarded=o.discarded,
            anomalies=o.anomalies, host_failures=o.host_failures, rejections=o.rejections,
            refused=e.refused, accepted_total=e.accepted_total, finished_total=e.finished_total,
            running=len(e.running), active_programs=o.active(), blacklisted=self.view.blacklisted(),
            reports_received=self.view.reports_received, learned_work=self.origin.learned_work(),
            moves=o.moves, moves_aborted=o.moves_aborted,
        )
