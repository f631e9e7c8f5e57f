"""The discrete-event simulator: a team of robots in virtual time.

How this works: one heap of timed events drives everything. Each simulated
robot has a ``CPU`` (processor sharing), a load publisher that reports every
``publisher.period`` seconds averaged over ``publisher.window`` (so decisions
use stale information, as on real robots), and a ``ramps.core.node.Node``,
the very same object the real runtime drives. The simulator only applies the
node's actions: ``Send`` becomes a message on a link with latency, bandwidth
and queueing; ``StartProgram`` a job on the CPU; ``Deliver`` a record. No
placement or recovery logic lives here. In a fleet (more robots than
``placement_sample``) heartbeats go by mailbox, read in batches (``ramps.sim.fleet``).
A robot with ``handling`` handles each message it receives up to that much
later, in order, as a node on a throttled core does.

Faults (``ramps.sim.faults``): ``crash`` removes the robot and all its state (a new incarnation
starts on ``recover``); ``network`` isolates it while it keeps computing;
``freeze`` stops it entirely (SIGSTOP) with its state kept; ``battery`` sets its
charge (``ramps.sim.battery``, read before each report); ``load`` changes
how many busy processes the robot's own software runs (load that changes
after placement). Programs with ``checkpoint_every`` save their state that
often while they run (``CheckpointSaved``); a restart that carries it
resumes with only the work left. Messages in flight across a link that goes down are lost. With liveliness on, teammates
learn of a crash after ``network.crash_detect`` and of a cut or freeze after
``network.lease``, as Zenoh reports them.

Determinism: one ``random.Random(seed)`` feeds the simulator, and each node
gets its own generator seeded from it; ties in time are broken by insertion
order. The same scenario and seed give the same trace.
"""

from __future__ import annotations

import gc
import heapq
import itertools
import math
import random
import time as _wallclock  # only for reporting how long a run took
from typing import Any, Callable

from ramps.core.accelerators import parse_accelerator
from ramps.core.cadence import ReportCadence
from ramps.core.cost import NetworkEstimate, nice_weight, program_cores
from ramps.core.events import (Action, CheckpointSaved, Deliver, Note, ProgramFinished,
                               PublishReport, Received, Send, StartProgram, StopProgram, Submit)
from ramps.core.fanout import report_targets
from ramps.core.messages import Heartbeat, LoadReport, Message
from ramps.core.node import Node
from ramps.core.speed import REMEASURE_PERIOD, SpeedMeasured
from ramps.sim.battery import Batteries
from ramps.sim.cpu import CPU, next_completion, take_finished
from ramps.sim.faults import apply_fault
from ramps.sim.fleet import Mailboxes
from ramps.sim.results import ProgramRecord, SimResult, TraceEntry, running_where, tally
from ramps.sim.scenario import FaultSpec, ProgramSpec, RobotSpec, Scenario
from ramps.sim.wire import wire_size


class _Robot:
    __slots__ = ("spec", "node", "cpu", "accel", "alive", "net_up", "frozen", "incarnation", "epoch",
                 "wake_at", "wake_token", "done_token", "pub_phase", "remeasure_at", "record", "handled", "timed",
                 "cadence")
    #: the robot's node and CPU, made by each boot (``Simulator._setup`` boots
    #: every robot before the first event). A crashed robot keeps its last
    #: ones until it recovers, unused: everything that reaches them checks
    #: ``alive`` (or the incarnation) first
    node: Node
    cpu: CPU
    #: its accelerators by kind, each a pool of slots shared like cores
    accel: dict[str, CPU]

    def __init__(self, spec: RobotSpec) -> None:
        self.spec = spec
        self.alive, self.net_up, self.frozen = False, True, False
        self.incarnation = 0
        #: bumped whenever the robot's links break, to drop messages in flight
        self.epoch = 0
        self.wake_at = math.inf
        #: its node's deadline was read since its boot (``Simulator._apply``): its wake is scheduled
        self.timed = False
        self.wake_token = self.done_token = 0
        self.pub_phase = 0.0
        #: which of its periodic reports go on the wire (``ramps.core.cadence``), made by each boot
        self.cadence = ReportCadence()
        #: when its node measures its speed again (``ramps.core.speed``)
        self.remeasure_at = 0.0
        #: its durable record as its node last wrote it (``RobotSpec.record``)
        self.record: list[bytes] = []
        #: when its node handles the last message it has received (``RobotSpec.handling``)
        self.handled = 0.0

    @property
    def reachable(self) -> bool:
        return self.alive and self.net_up and not self.frozen


class Simulator:
    def __init__(self, scenario: Scenario, *, policy: str | None = None, seed: int | None = None,
                 trace: bool = False, snapshots: list[float] | None = None, deadlines: bool = True) -> None:
        self.sc = scenario.check()
        #: whether origins are told the programs' deadlines (False: placed as
        #: if they had none, their misses still counted)
        self.deadlines = deadlines
        self.policy = policy or scenario.policy
        self.seed = scenario.seed if seed is None else seed
        self.rng = random.Random(self.seed)
        self.now = 0.0
        self._heap: list[tuple[float, int, Callable[..., None], Any]] = []
        self._seq = itertools.count(1)  # ties in time: in the order scheduled
        self.robots: dict[str, _Robot] = {r.name: _Robot(r) for r in self.sc.team()}
        self.names = list(self.robots)
        self.net = self.sc.network
        #: (sender, receiver) -> [when the link is free, its latency, its bandwidth]
        self._links: dict[tuple[str, str], list[float]] = {}
        self.records: dict[str, ProgramRecord] = {}
        self._true_work: dict[str, float] = {}
        self._true_accel: dict[str, float] = {}
        self._result_size: dict[str, int] = {}
        #: programs that checkpoint: seconds between checkpoints, bytes of each
        self._checkpoint: dict[str, tuple[float, int]] = {}
        self.subscribers = sorted({p.origin for p in self.sc.programs})
        self._submitters = frozenset(self.subscribers)
        #: the origins each robot's load reports go to (all of them but in a fleet: ``ramps.core.fanout``)
        self._report_to = {name: report_targets(name, self.subscribers, len(self.robots), self.sc.config)
                           or self.subscribers for name in self.robots}
        #: seconds between two periodic reports on the wire, as a node's in a team of this size
        self._report_period = self.sc.config.report_period(self.sc.publisher.period, len(self.robots) - 1)
        self._hearing: dict[_Robot, list[_Robot]] = {}  # ``_report_to`` as robots, made as needed
        #: a fleet's heartbeats go by mailbox, read in batches (``ramps.sim.fleet``); None: a team
        self.mail = Mailboxes(self) if 0 < self.sc.config.placement_sample < len(self.robots) else None
        self._pending = self.events = self.sent = self.dropped = 0
        self._trace_on = trace
        self.trace: list[TraceEntry] = []
        self._snap_times = sorted(snapshots or [])
        self.snapshots: dict[str, dict[str, int]] = {}
        self.batteries = Batteries(self.sc.team())
        self._first_submit, self._last_delivery = math.inf, 0.0

    # ================================================================ event heap
    def _at(self, t: float, fn: Callable[..., None], arg: Any = None) -> None:
        heapq.heappush(self._heap, (t, next(self._seq), fn, arg))

    def run(self) -> SimResult:
        started = _wallclock.perf_counter()
        # a run's objects hold no cycles to collect (none at 1,000 robots), and the
        # collector's passes over their millions cost a tenth of the run: off until it ends
        collecting, events = gc.isenabled(), 0
        gc.disable()
        try:
            self._setup()
            until = self.sc.until if self.sc.until is not None else 86_400.0
            heap, pop = self._heap, heapq.heappop
            while heap and self._pending > 0:
                t, _, fn, arg = pop(heap)
                if t > until:
                    self.now = until
                    break
                self.now = t
                events += 1
                fn(arg)
        finally:
            self.events += events
            if collecting:
                gc.enable()
        return self._result(_wallclock.perf_counter() - started)

    # ================================================================ setup
    def _setup(self) -> None:
        for r in self.robots.values():
            self._boot(r, 0.0)
        w = self.sc.warmup
        bursts: dict[tuple[float, str], list[ProgramSpec]] = {}  # an origin's programs of one instant: one batch
        for entry in self.sc.programs:
            t = w + entry.at
            for i in range(entry.count):
                jitter = self.rng.uniform(-entry.jitter, entry.jitter) if entry.jitter else 0.0
                when = max(w, t + i * entry.spacing + jitter)
                self._pending += 1
                bursts.setdefault((when, entry.origin), []).append(entry)
        for (when, _), entries in bursts.items():
            self._at(when, self._submit, entries)
        for f in self.sc.faults:
            self._at(w + f.at, self._fault, f)
        for t in self._snap_times:
            self._at(w + t, self._snapshot, t)

    def _boot(self, r: _Robot, now: float) -> None:
        spec = r.spec
        r.incarnation += 1
        r.alive, r.net_up, r.frozen = True, True, False
        r.epoch += 1
        weight = nice_weight(spec.worker_nice)
        r.cpu = CPU(program_cores(spec.cores, spec.node_cpu), spec.speed, spec.background, now, weight=weight)
        accels = [parse_accelerator(text) for text in spec.accelerators]
        r.accel = {a.kind: CPU(a.count, a.speed, 0, now) for a in accels}
        r.node = Node(
            spec.name, cores=spec.cores, speed=spec.measured_speed or spec.speed, policy=self.policy, config=self.sc.config,
            rng=random.Random(self.rng.getrandbits(64)), incarnation=r.incarnation,
            net=NetworkEstimate(latency=self.net.latency, bandwidth=self.net.bandwidth), program_weight=weight,
            accelerators=accels, bursts=True, submits=spec.name in self._submitters,
        )
        r.node.executor.background = float(spec.background)
        r.wake_at, r.timed = math.inf, False
        r.remeasure_at = now + REMEASURE_PERIOD
        r.pub_phase = self.rng.uniform(0.0, self.sc.publisher.period)
        r.cadence = ReportCadence()
        self._at(now + r.pub_phase, self._publish, (r, r.incarnation))

    # ================================================================ node driving
    def _apply(self, r: _Robot, actions: list[Action]) -> None:
        node = r.node
        for a in actions:  # none, mostly (a report heard)
            if isinstance(a, Send):
                if self.mail is not None and type(a.msg) is Heartbeat:
                    self.mail.beat(r, a.to, a.msg)
                else:
                    self._send(r, a.to, a.msg)
            elif isinstance(a, StartProgram):
                work = (self._true_accel if a.accelerator else self._true_work).get(a.program_id, a.work)
                if a.resume is not None:
                    work *= 1.0 - a.resume_fraction
                (r.accel[a.accelerator] if a.accelerator else r.cpu).add((a.program_id, a.attempt), work, self.now)
                self._cpu_changed(r)
                every = self._checkpoint.get(a.program_id)
                if every is not None:
                    self._at(self.now + every[0], self._save_checkpoint,
                             (r, r.incarnation, a.program_id, a.attempt, work, a.resume_fraction if a.resume else 0.0))
            elif isinstance(a, StopProgram):
                if any(pool.remove((a.program_id, a.attempt), self.now) for pool in (r.cpu, *r.accel.values())):
                    self._cpu_changed(r)
            elif isinstance(a, Deliver):
                self._delivered(r, a)
            elif isinstance(a, PublishReport):
                self._broadcast(r, a.report)
            elif isinstance(a, Note):
                if self._trace_on:
                    self.trace.append(TraceEntry(self.now, node.robot, a.what, a.program_id, a.robot, a.attempt, a.detail))
        r.timed = True
        d = node.next_deadline()  # when to wake it next
        if d is not None and d < r.wake_at:
            r.wake_at = d
            r.wake_token += 1
            self._at(d if d > self.now else self.now, self._wake, (r, r.wake_token))

    def _handle(self, r: _Robot, event) -> None:
        self._apply(r, r.node.handle(event, self.now))

    def _wake(self, arg: tuple[_Robot, int]) -> None:
        r, token = arg
        if token != r.wake_token or not r.alive:
            return
        r.wake_at = math.inf
        if r.frozen:
            return  # a frozen robot's timers fire when it thaws
        self._apply(r, r.node.tick(self.now))

    # ================================================================ CPU
    def _cpu_changed(self, r: _Robot) -> None:
        r.done_token += 1
        nxt = next_completion((r.cpu, *r.accel.values()))
        if nxt is not None:
            self._at(nxt, self._cpu_done, (r, r.done_token, r.incarnation))

    def _cpu_done(self, arg: tuple[_Robot, int, int]) -> None:
        r, token, inc = arg
        if token != r.done_token or inc != r.incarnation or not r.alive:
            return
        finished = take_finished((r.cpu, *r.accel.values()), self.now)
        self._cpu_changed(r)
        for pid, attempt in finished:
            self._handle(r, ProgramFinished(program_id=pid, attempt=attempt, ok=True,
                                            value=b"", result_size=self._result_size.get(pid, 0)))

    def _save_checkpoint(self, arg: tuple[_Robot, int, str, int, float, float]) -> None:
        """A running program saves its state (``ramps.checkpoint``)."""
        r, inc, pid, attempt, work, base = arg
        if inc != r.incarnation or not r.alive or (pid, attempt) not in r.cpu.jobs:
            return
        every, size = self._checkpoint[pid]
        self._at(self.now + every, self._save_checkpoint, arg)
        if r.frozen:
            return
        r.cpu.advance(self.now)
        left = max(0.0, r.cpu.jobs[(pid, attempt)])
        fraction = min(1.0, base + (1.0 - base) * (1.0 - left / work)) if work > 0 else base
        self._handle(r, CheckpointSaved(program_id=pid, attempt=attempt, state=bytes(size), fraction=fraction))

    # ================================================================ load publisher
    def _publish(self, arg: tuple[_Robot, int]) -> None:
        r, inc = arg
        if inc != r.incarnation or not r.alive:
            return
        pub = self.sc.publisher
        self._at(self.now + pub.period, self._publish, arg)
        if r.frozen:
            return
        busy, runnable, ramps_avg = r.cpu.averages(self.now, pub.window)
        if r.spec.measured_speed is not None and self.now >= r.remeasure_at and not r.cpu.jobs:
            # a robot that mis-measured at boot measures again while idle, as a
            # node does (ramps.runtime.node); idle, it measures its true speed
            # (a node's figure is the mean of its latest measurements,
            # ramps.runtime.speed_probe.SpeedSamples: the odd boot figure is outweighed)
            r.remeasure_at = self.now + REMEASURE_PERIOD
            self._handle(r, SpeedMeasured(speed=r.spec.speed))
        for reading in self.batteries.sample(r.spec.name, r.cpu, self.now):  # below its reserve: hands back
            self._handle(r, reading)
        report = r.node.make_report(cpu_busy=busy, runnable=runnable, ramps_avg=ramps_avg, window=pub.window,
                                    mem_free=r.spec.memory, node_cpu=r.spec.node_cpu)
        if r.spec.name in self._submitters:
            self._handle(r, Received(sender=r.spec.name, msg=report))
        if r.cadence.due(report, self.now, self._report_period, pub.period):
            self._broadcast(r, report)

    def _broadcast(self, r: _Robot, report: LoadReport) -> None:
        """A load report on its way to every robot that places programs (in
        a fleet with ``report_fanout``, to a few of them: ``ramps.core.fanout``)."""
        if not r.net_up:
            return
        delay = self.net.latency + wire_size(report) / self.net.bandwidth
        self._at(self.now + delay, self._deliver_report, (r, r.epoch, report))

    def _deliver_report(self, arg: tuple[_Robot, int, LoadReport]) -> None:
        src, epoch, report = arg
        if epoch != src.epoch:
            return
        event = Received(sender=src.spec.name, msg=report)  # frozen: one for every robot that hears it
        loss, now, apply = self.net.loss, self.now, self._apply
        for dst in self._hearers(src):
            if not (dst.alive and dst.net_up and not dst.frozen) or (loss and self.rng.random() < loss):
                continue
            if dst.spec.handling:
                self._later(dst, event)
                continue
            actions = dst.node.handle(event, now)
            if actions or not dst.timed:  # a report heard with no action sets no timer: the wake stands
                apply(dst, actions)

    def _later(self, dst: _Robot, event: Received) -> None:
        """A message that ``dst``'s node handles a random while later, in the order received (a node
        on a throttled core waits for its next share of it: ``RobotSpec.handling``)."""
        dst.handled = max(self.now + self.rng.random() * dst.spec.handling, dst.handled)
        self._at(dst.handled, self._handle_late, (dst, dst.incarnation, dst.epoch, event))

    def _handle_late(self, arg: tuple[_Robot, int, int, Received]) -> None:
        dst, inc, epoch, event = arg
        if inc == dst.incarnation and epoch == dst.epoch and dst.alive and dst.net_up and not dst.frozen:
            self._apply(dst, dst.node.handle(event, self.now))

    def _hearers(self, src: _Robot) -> list[_Robot]:
        """The robots ``src``'s load reports go to (``_report_to``), but itself."""
        out = self._hearing.get(src)
        if out is None:
            out = self._hearing[src] = [self.robots[n] for n in self._report_to[src.spec.name] if n != src.spec.name]
        return out

    # ================================================================ network
    def _send(self, src: _Robot, to: str, msg: Message) -> None:
        self.sent += 1
        dst = self.robots.get(to)
        if (dst is None or not (src.alive and src.net_up and not src.frozen)
                or not (dst.alive and dst.net_up and not dst.frozen)
                or (self.net.loss and self.rng.random() < self.net.loss)):
            self.dropped += 1
            return
        link = self._links.get((src.spec.name, to)) or self._link(src, dst)
        now = self.now
        link[0] = (link[0] if link[0] > now else now) + wire_size(msg) / link[2]
        self._at(link[0] + link[1], self._arrive, (src, src.epoch, dst, dst.epoch, msg))

    def _link(self, src: _Robot, dst: _Robot) -> list[float]:
        latency, bandwidth = self.net.latency, self.net.bandwidth
        for end in (src.spec, dst.spec):  # a robot's own worse link counts
            latency = latency if end.latency is None else max(latency, end.latency)
            bandwidth = bandwidth if end.bandwidth is None else min(bandwidth, end.bandwidth)
        link = self._links[(src.spec.name, dst.spec.name)] = [0.0, latency, bandwidth]
        return link

    def _arrive(self, arg: tuple[_Robot, int, _Robot, int, Message]) -> None:
        src, se, dst, de, msg = arg
        if se != src.epoch or de != dst.epoch or not (dst.alive and dst.net_up and not dst.frozen):
            self.dropped += 1
        elif dst.spec.handling:
            self._later(dst, Received(sender=src.spec.name, msg=msg))
        else:
            self._apply(dst, dst.node.handle(Received(sender=src.spec.name, msg=msg), self.now))

    # ================================================================ workload
    def _submit(self, entries: list[ProgramSpec]) -> None:
        """An origin's programs submitted at one instant: one batch of its node's (``Node.flush``)."""
        r = self.robots[entries[0].origin]
        actions = [a for entry in entries for a in self._submit_one(r, entry)]
        if r.alive:
            self._apply(r, actions + r.node.flush(self.now))

    def _submit_one(self, origin: _Robot, entry: ProgramSpec) -> list[Action]:
        pid = f"{entry.origin}#{len(self.records) + 1}"
        due = None if entry.deadline is None else self.now + entry.deadline
        self.records[pid] = ProgramRecord(program_id=pid, origin=entry.origin, submitted_at=self.now, deadline=due)
        self._first_submit = min(self._first_submit, self.now)
        if not origin.alive:
            self._pending -= 1  # an origin that is down submits nothing
            self.records[pid].error = "origin down at submit time"
            return []
        self._true_work[pid] = entry.work
        self._true_accel[pid] = entry.accelerator_work or entry.work
        self._result_size[pid] = entry.result
        if entry.checkpoint_every > 0:
            self._checkpoint[pid] = (entry.checkpoint_every, entry.checkpoint_size)
        return origin.node.handle(Submit(
            program_id=pid, program=entry.program, payload_size=entry.payload,
            work=entry.work_estimate if entry.work_estimate is not None else entry.work,
            result_size=entry.result, memory=entry.memory,
            deadline=due if self.deadlines else None, on_miss=entry.on_miss, accelerator=entry.accelerator,
            accelerator_work=entry.accelerator_estimate or entry.accelerator_work or 0.0,
            cpu_fallback=entry.cpu_fallback,
        ), self.now)

    def _delivered(self, r: _Robot, d: Deliver) -> None:
        rec = self.records[d.program_id]
        rec.deliveries += 1
        if rec.deliveries > 1:
            return
        rec.delivered_at = self.now
        rec.host, rec.ok, rec.attempts, rec.error = d.host, d.ok, d.attempts, d.error
        rec.moves, rec.resumed_from = d.moves, d.resumed_from
        self._pending -= 1
        self._last_delivery = max(self._last_delivery, self.now)

    # ================================================================ faults
    def _fault(self, f: FaultSpec) -> None:
        apply_fault(self, f)

    # ================================================================ results
    def _snapshot(self, label: float) -> None:
        self.snapshots[f"{label:g}"] = running_where(self.robots, self.records)

    def _result(self, wall: float) -> SimResult:
        dist, completed, failed, lost, dup, deadlines, misses = tally(self.records.values(), self.names)
        stats = [r.node.statistics() for r in self.robots.values()]
        energy, charge = self.batteries.finish({n: r.cpu for n, r in self.robots.items() if r.alive}, self.now)
        first = self._first_submit if self._first_submit < math.inf else 0.0
        return SimResult(
            scenario=self.sc.name, policy=self.policy, seed=self.seed, robots=self.names,
            distribution=dist, makespan=max(0.0, self._last_delivery - first), completed=completed,
            failed=failed, lost=lost, duplicated=dup, programs=list(self.records.values()),
            statistics=stats, snapshots=self.snapshots, events=self.events, messages_sent=self.sent,
            messages_dropped=self.dropped + (self.mail.lost if self.mail else 0), end_time=self.now, wall_seconds=wall, trace=self.trace,
            deadlines=deadlines, deadline_misses=misses, energy=energy, charge=charge,
        )


def simulate(scenario: Scenario, *, policy: str | None = None, seed: int | None = None,
             trace: bool = False, snapshots: list[float] | None = None, deadlines: bool = True) -> SimResult:
    """Run one scenario to completion and return what happened
    (``deadlines=False``: the programs' deadlines are not told to their
    origins, only counted)."""
    return Simulator(scenario, policy=policy, seed=seed, trace=trace, snapshots=snapshots,
                     deadlines=deadlines).run()
