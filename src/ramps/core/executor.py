"""The program executor: runs registered programs for any teammate.

How this works: an ``OffloadRequest`` is accepted (``StartProgram`` for the driver,
``OffloadAccepted`` for the origin) or turned away with a reason: ``unknown_program`` and
``bad_request`` are permanent, ``busy`` means the host has more runnable work than the origin
expected (ramps negotiation) and the origin should place again at once, ``late`` that the program
would compute here for longer than its deadline leaves (``deadline_in``), or would slow a program
running here past a deadline it would have met (by processor sharing of the work each has left;
checked for offers that negotiate, not forced ones). While programs run, the executor sends each
origin one ``Heartbeat`` per period listing its programs; a program's progress goes to its origin at
once, or with the next heartbeat if some went less than a period ago (``ProgramProgress``, the
newest only). A result is sent to the origin and kept, resent every ``result_resend`` seconds, until
the origin acknowledges it, so a result survives a lost message or an origin that is briefly cut
off.

An origin whose liveliness is lost (its robot crashed or left the network)
and does not come back within ``origin_gone_after`` (``RampsConfig.origin_hold``)
is gone for good: its running programs are stopped and its unacknowledged
results dropped, instead of running for nobody and being resent for
``result_retention``. An origin that comes back within it, a new
incarnation included (a node restarted with its durable record,
``ramps.core.durable``), receives their heartbeats and results as before.

A program offered for one of this robot's accelerators (``OffloadRequest.accelerator``)
runs there: it shares that kind's slots with the programs on them, not the
cores, and is neither in the CPU counts nor in ``remaining``; a robot
without that kind turns it away (``accelerator``). Its result tells the work
it took there (``ProgramResult.work_done``: the seconds it held a slot, at
the slot's speed), which its origin learns (``ramps.core.learning``).

Requests are idempotent: the same (program, attempt) twice is accepted once.
``accepted_total`` and ``finished_total`` only ever grow; the load publisher
puts them in every report so origins can tell what a report includes.
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Callable, Sequence

from ramps.core.accelerators import Accelerator, slot_share
from ramps.core.config import RampsConfig
from ramps.core.cost import program_share, shared_finish_time
from ramps.core.events import (Action, CheckpointSaved, Note, ProgramFinished, ProgressReported, Send, StartProgram,
                               StopProgram)
from ramps.core.messages import (MAX_LISTED, MAX_PROGRESS_TEXT, CancelProgram, Heartbeat, LoadReport, OffloadAccepted,
                                 OffloadRejected, OffloadRequest, ProgramCheckpoint, ProgramProgress, ProgramRef,
                                 ProgramResult, ResultAck)

Key = tuple[str, int]
#: seconds an origin may be lost (liveliness) before its programs here are
#: stopped, by default (``RampsConfig.origin_hold``)
ORIGIN_GONE_AFTER = RampsConfig().origin_hold


class _Job:
    __slots__ = ("origin", "program", "started_at", "progress", "detail", "progress_new", "progress_sent_at",
                 "work", "done", "due", "accelerator")

    def __init__(self, origin: str, program: str, started_at: float, work: float = 0.0,
                 due: float | None = None, accelerator: str = "") -> None:
        self.origin = origin
        #: the kind of accelerator it runs on ("" = a CPU); its work is work there
        self.accelerator = accelerator
        self.program = program
        self.started_at = started_at
        #: the origin's estimate of the work, and how much of it processor
        #: sharing has done by ``Executor._advanced_at`` (see ``remaining``)
        self.work = work
        self.done = 0.0
        #: when its origin wants the result, in this robot's time (None: no deadline)
        self.due = due
        #: the latest progress the program reported, and whether the origin has it yet
        self.progress: float | None = None
        self.detail = ""
        self.progress_new = False
        self.progress_sent_at = -float("inf")


class Executor:
    def __init__(
        self,
        me: str,
        *,
        config: RampsConfig,
        registry: frozenset[str] | None = None,
        incarnation: int = 0,
        cores: float = float("inf"),
        speed: float = 1.0,
        program_weight: float = 1.0,
        core_fraction: float = 1.0,
        accelerators: Sequence[Accelerator] = (),
    ) -> None:
        self.me = me
        #: this robot's accelerators by kind, and how many programs run on each
        self.accelerators = {a.kind: a for a in accelerators}
        self.on_accelerators = {a.kind: 0 for a in accelerators}
        self._on_any = 0
        self._with_due = 0  # running programs with a deadline (none: ``_makes_late`` walks none)
        self.config = config
        #: the share of a CPU each of this robot's cores is (a quota shared by
        #: its cores; 1 without one): a program's CPU second is this robot's
        #: ``speed / core_fraction`` work units
        self.core_fraction = core_fraction
        #: names of the programs installed here; None accepts any name
        self.registry = registry
        self.incarnation = incarnation
        self.running: dict[Key, _Job] = {}
        #: the heartbeat to each origin of the programs running here (None: to be made again at the next tick)
        self._beats: dict[str, Heartbeat] | None = None
        self._outbox: dict[Key, tuple[str, ProgramResult, float, float]] = {}
        self._next_tick: float | None = None
        #: origins whose liveliness went, and when (see on_origin_lost)
        self._origins_lost: dict[str, float] = {}
        self.origin_gone_after = self.config.origin_hold
        #: programs stopped because their origin was gone for good
        self.orphans_stopped = 0
        #: runnable tasks that are not ramps programs, as the driver measures
        self.background = 0.0
        self.accepted_total = 0
        self.finished_total = 0
        self.refused = 0
        #: the node is shutting down: take nothing new
        self.closing = False
        #: below its battery reserve (``ramps.core.battery``): no teammates' programs
        self.low_battery = False
        #: this robot's capacity, for admission (a program that gets a whole
        #: core is never turned away; see ``_still_best_here``)
        self.cores = cores
        self.speed = speed
        self.program_weight = program_weight
        self._advanced_at: float | None = None

    # ------------------------------------------------------------ inputs
    def _advance(self, now: float) -> None:
        """Credit every running program with the work processor sharing did
        for it since the last call (the count and background of that time)."""
        last, self._advanced_at = self._advanced_at, now
        if last is None or now <= last or not self.running:
            return
        if not self._on_any:
            rate = self.speed * program_share(self.cores, len(self.running), self.background, self.program_weight)
            step = rate * (now - last)
            for job in self.running.values():
                job.done += step
            return
        cpu = len(self.running) - self._on_any
        steps = {"": self.speed * program_share(self.cores, cpu, self.background, self.program_weight)
                 * (now - last) if cpu else 0.0}
        for kind, a in self.accelerators.items():
            steps[kind] = a.speed * slot_share(a.count, self.on_accelerators[kind]) * (now - last)
        for job in self.running.values():
            job.done += steps[job.accelerator]

    def _pool(self, kind: str) -> tuple[list[_Job], float, float, float, float]:
        """The programs sharing what a program on ``kind`` ("" = a CPU) would
        share, and that pool's (cores or slots, speed, background, weight)."""
        jobs = [job for job in self.running.values() if job.accelerator == kind]
        if kind:
            a = self.accelerators[kind]
            return jobs, float(a.count), a.speed, 0.0, 1.0
        return jobs, self.cores, self.speed, self.background, self.program_weight

    def _started(self, key: Key, job: _Job) -> None:
        self.running[key] = job
        self._beats = None
        self._with_due += job.due is not None
        if job.accelerator:
            self.on_accelerators[job.accelerator] += 1
            self._on_any += 1

    def _ended(self, key: Key) -> _Job | None:
        job = self.running.pop(key, None)
        self._beats = None
        self._with_due -= job is not None and job.due is not None
        if job is not None and job.accelerator:
            self.on_accelerators[job.accelerator] -= 1
            self._on_any -= 1
        return job

    def cpu_programs(self) -> int:
        """Programs running here on a CPU (not on an accelerator)."""
        return len(self.running) - self._on_any

    def set_speed(self, speed: float, now: float) -> None:
        """This robot's speed changed (``ramps.core.speed``): programs were credited at the old one until ``now``."""
        self._advance(now)
        self.speed = speed

    def remaining(self, now: float, kind: str = "") -> list[float]:
        """Work units each running program has left by the estimate above,
        smallest first, at most MAX_LISTED (what load reports carry): those
        on a CPU, or with ``kind`` those on that kind of accelerator."""
        self._advance(now)
        # x if x > 0.0 else 0.0 is max(0.0, x) without a call per job; a
        # robot running more than MAX_LISTED lists the smallest, without sorting the rest
        left = [x if (x := job.work - job.done) > 0.0 else 0.0 for job in self.running.values()
                if job.accelerator == kind]
        if len(left) > MAX_LISTED:
            return heapq.nsmallest(MAX_LISTED, left)
        left.sort()
        return left

    def on_offload(self, req: OffloadRequest, now: float, out: list[Action],
                   report_now: Callable[[], LoadReport] | None = None) -> None:
        self._advance(now)
        key = (req.program_id, req.attempt)
        if key in self.running or key in self._outbox:
            # a repeated request: say yes again, start nothing
            out.append(Send(to=req.origin, msg=OffloadAccepted(
                program_id=req.program_id, attempt=req.attempt, host=self.me, accept_seq=self.accepted_total)))
            return
        reject = None
        if req.host != self.me:
            reject = ("bad_request", True, f"request for host {req.host!r} reached {self.me!r}")
        elif self.registry is not None and req.program not in self.registry:
            reject = ("unknown_program", True, f"no program {req.program!r} is registered on {self.me}")
        elif self.closing:
            reject = ("closing", False, f"{self.me} is shutting down")
        elif self.low_battery and req.origin != self.me:
            reject = ("battery", False, f"{self.me} is below its battery reserve: it runs no teammates' programs")
        elif req.accelerator and req.accelerator not in self.accelerators:
            reject = ("accelerator", False, f"{self.me} has no {req.accelerator!r} accelerator")
        elif not req.force and (req.deadline_in is not None or req.expected_runnable is not None) and (
                late := self._makes_late(req)) is not None:
            reject = ("late", False, late)
        elif req.expected_runnable is not None and not req.force:
            # turned away only if the program would not get a whole core here
            # and more is running than the origin counted on (several origins
            # deciding on the same data); the rejection carries a fresh report
            if req.accelerator:
                slots: float = self.accelerators[req.accelerator].count
                actual, other = float(self.on_accelerators[req.accelerator]), 0.0
            else:
                slots, actual, other = self.cores, self.background + self.cpu_programs(), self.background
            if (actual + 1.0 > slots and actual > req.expected_runnable + self.config.admission_slack
                    and not self._still_best_here(req)):
                reject = ("busy", False, f"{actual:.1f} runnable here ({other:.1f} besides programs), "
                                         f"origin expected {req.expected_runnable:.1f}")
        if reject is not None:
            self.refused += 1
            reason, permanent, detail = reject
            out.append(Note(what="refused", program_id=req.program_id, robot=req.origin,
                            attempt=req.attempt, detail=detail))
            out.append(Send(to=req.origin, msg=OffloadRejected(
                program_id=req.program_id, attempt=req.attempt, host=self.me, reason=reason,
                permanent=permanent, detail=detail,
                report=report_now() if (report_now is not None and not permanent) else None)))
            return
        self.accepted_total += 1
        due = now + req.deadline_in if req.deadline_in is not None else None
        self._started(key, _Job(req.origin, req.program, now, req.work, due, req.accelerator))
        out.append(StartProgram(program_id=req.program_id, attempt=req.attempt, origin=req.origin,
                                program=req.program, args=req.args, work=req.work, resume=req.resume,
                                resume_fraction=req.resume_fraction, accelerator=req.accelerator))
        out.append(Send(to=req.origin, msg=OffloadAccepted(
            program_id=req.program_id, attempt=req.attempt, host=self.me, accept_seq=self.accepted_total)))
        if self._next_tick is None:
            self._next_tick = now + self.config.heartbeat_period

    def _still_best_here(self, req: OffloadRequest) -> bool:
        """Busier than the origin thought, but the program still computes
        here within the time it would take on the origin's best other robot
        (``time_budget``): take it."""
        if req.time_budget is None:
            return False
        return self._time_here(req) <= req.time_budget * (1.0 + self.config.admission_tolerance)

    def _makes_late(self, req: OffloadRequest) -> str | None:
        """Why taking ``req`` would miss a deadline (its own, or that of a
        program running here that would have made it), by processor sharing
        of the work each has left; None if it would not. ``_advance`` first."""
        if req.deadline_in is None and not self._with_due:
            return None  # no program here has a deadline: no walk over them
        jobs, *pool = self._pool(req.accelerator)
        if req.deadline_in is None and not any(job.due is not None for job in jobs):
            return None
        tol = 1.0 + self.config.admission_tolerance
        left = [max(0.0, job.work - job.done) for job in jobs]
        after = self._ends(left + [req.work], *pool)
        if req.deadline_in is not None and after[-1] > req.deadline_in * tol:
            return f"would end in {after[-1]:.2f} s here, deadline in {req.deadline_in:.2f} s"
        if self._advanced_at is None:
            return None
        now = self._advanced_at
        before = self._ends(left, *pool)
        # no tolerance here: it is for the origin's estimate of the offer,
        # and a program here pushed past its deadline by any margin misses it
        hurt = sum(1 for job, b, a in zip(jobs, before, after)
                   if job.due is not None and b <= job.due - now < a)
        if hurt:
            return f"would make {hurt} program{'s' if hurt > 1 else ''} here miss {'their' if hurt > 1 else 'its'} deadline"
        return None

    @staticmethod
    def _ends(left: list[float], cores: float, speed: float, background: float, weight: float) -> list[float]:
        """Seconds until each program with these works left ends in a pool
        of ``cores`` (``_pool``), under processor sharing (equal rates: the
        smallest ends first)."""
        out = [0.0] * len(left)
        t = done = 0.0
        k = len(left)
        for i in sorted(range(len(left)), key=left.__getitem__):
            rate = speed * program_share(cores, k, background, weight)
            t += (left[i] - done) / rate
            done = left[i]
            out[i] = t
            k -= 1
        return out

    def _time_here(self, req: OffloadRequest) -> float:
        """Seconds the offered program would compute here, under processor
        sharing with what runs here now (by the work each has left)."""
        jobs, cores, speed, background, weight = self._pool(req.accelerator)
        others = [max(0.0, job.work - job.done) for job in jobs]
        return shared_finish_time(req.work, others, cores, speed, background, weight)

    def on_finished(self, ev: ProgramFinished, now: float, out: list[Action]) -> None:
        self._advance(now)
        key = (ev.program_id, ev.attempt)
        job = self._ended(key)
        if job is None:
            return  # cancelled before it ended: nobody wants it
        self.finished_total += 1
        result = ProgramResult(
            program_id=ev.program_id, attempt=ev.attempt, host=self.me, ok=ev.ok, value=ev.value,
            error=ev.error, result_size=ev.result_size, retryable=ev.retryable, finish_seq=self.finished_total,
            work_done=self._work_done(job, ev) if ev.ok else None, worker_died=ev.retryable and ev.worker_died,
        )
        self._outbox[key] = (job.origin, result, now + self.config.result_resend, now + self.config.result_retention)
        out.append(Send(to=job.origin, msg=result))
        if self._next_tick is None:
            self._next_tick = now + self.config.result_resend

    def _work_done(self, job: _Job, ev: ProgramFinished) -> float | None:
        """The work a finished program took, in units at this robot's speed:
        from the CPU seconds it used where the driver measured them (exact
        whatever its share of the robot was, however long it slept),
        else from processor sharing at this robot's speed and load. On an
        accelerator, its work there (its origin learns it apart,
        ``ramps.core.learning``; its CPU seconds say nothing of it): the
        seconds it held a slot at the slot's speed, where the driver measured
        them, else what processor sharing of the slots did for it."""
        cpu = ev.cpu_s
        if job.accelerator:
            held = ev.slot_s
            if held is None or not (math.isfinite(held) and held >= 0.0):
                return job.done
            return held * self.accelerators[job.accelerator].speed
        if cpu is None or not (math.isfinite(cpu) and cpu >= 0.0) or self.core_fraction <= 0.0:
            return job.done
        return cpu * self.speed / self.core_fraction

    def on_cancel(self, msg: CancelProgram, now: float, out: list[Action]) -> None:
        self._advance(now)
        key = (msg.program_id, msg.attempt)
        job = self.running.get(key)
        if job is not None and job.origin == msg.origin:
            self._ended(key)
            self.finished_total += 1
            out.append(StopProgram(program_id=msg.program_id, attempt=msg.attempt))
        entry = self._outbox.get(key)
        if entry is not None and entry[0] == msg.origin:
            del self._outbox[key]

    def on_progress(self, ev: ProgressReported, now: float, out: list[Action]) -> None:
        """Send progress to the origin at once if none went for a heartbeat
        period, else keep the newest for the next heartbeat tick (so a chatty
        program costs at most two messages a period, and a quiet one's news
        travels without waiting)."""
        job = self.running.get((ev.program_id, ev.attempt))
        if job is None:
            return  # ended or withdrawn meanwhile
        job.progress = min(1.0, max(0.0, ev.fraction)) if ev.fraction == ev.fraction else 0.0
        job.detail = ev.detail[:MAX_PROGRESS_TEXT]
        job.progress_new = True
        if now - job.progress_sent_at >= self.config.heartbeat_period:
            self._send_one_progress(ev.program_id, ev.attempt, job, now, out)
        elif self._next_tick is None:
            self._next_tick = now + self.config.heartbeat_period

    def on_checkpoint(self, ev: CheckpointSaved, now: float, out: list[Action]) -> None:
        """A running program saved its state: send it to its origin (which
        keeps the latest, for a restart after a move or a failure)."""
        job = self.running.get((ev.program_id, ev.attempt))
        if job is None:
            return  # ended or withdrawn meanwhile
        fraction = ev.fraction if ev.fraction is not None and 0.0 <= ev.fraction <= 1.0 else None
        out.append(Send(to=job.origin, msg=ProgramCheckpoint(
            program_id=ev.program_id, attempt=ev.attempt, host=self.me, state=ev.state, fraction=fraction)))

    def on_ack(self, msg: ResultAck) -> None:
        entry = self._outbox.get((msg.program_id, msg.attempt))
        if entry is not None and entry[0] == msg.origin:
            del self._outbox[(msg.program_id, msg.attempt)]

    def on_origin_lost(self, robot: str, now: float) -> None:
        """``robot``'s liveliness went. If it has programs or results here and
        does not come back within ``origin_gone_after``, they are dropped
        (``tick``)."""
        if robot == self.me or robot in self._origins_lost:
            return
        if not any(j.origin == robot for j in self.running.values()) and \
                not any(e[0] == robot for e in self._outbox.values()):
            return
        self._origins_lost[robot] = now
        when = now + self.origin_gone_after
        self._next_tick = when if self._next_tick is None else min(self._next_tick, when)

    def on_origin_back(self, robot: str) -> None:
        self._origins_lost.pop(robot, None)

    def stop_origin(self, robot: str, now: float, out: list[Action]) -> None:
        """``robot`` may not have anything run here any more (revoked): stop its
        programs and drop its results now."""
        if robot != self.me:
            self._origins_lost[robot] = now - self.origin_gone_after
            self._drop_gone_origins(now, out)

    def _drop_gone_origins(self, now: float, out: list[Action]) -> None:
        for robot, since in list(self._origins_lost.items()):
            if now < since + self.origin_gone_after:  # the very sum tick() wakes at: no float gap
                continue
            del self._origins_lost[robot]
            for key, job in list(self.running.items()):
                if job.origin == robot:
                    self._ended(key)
                    self.finished_total += 1
                    self.orphans_stopped += 1
                    out.append(StopProgram(program_id=key[0], attempt=key[1]))
                    out.append(Note(what="origin_gone", program_id=key[0], robot=robot, attempt=key[1],
                                    detail=f"origin lost for {now - since:.1f} s: program stopped"))
            for key, entry in list(self._outbox.items()):
                if entry[0] == robot:
                    del self._outbox[key]
                    out.append(Note(what="origin_gone", program_id=key[0], robot=robot, attempt=key[1],
                                    detail=f"origin lost for {now - since:.1f} s: result dropped"))

    # ------------------------------------------------------------ timers
    def next_deadline(self) -> float | None:
        return self._next_tick

    def tick(self, now: float, out: list[Action]) -> None:
        self._advance(now)
        if self._next_tick is None or now < self._next_tick:
            return
        if self._origins_lost:
            self._drop_gone_origins(now, out)
        if self._beats is None:  # the programs running here changed since the last heartbeats
            by_origin: dict[str, list[ProgramRef]] = {}
            for (pid, attempt), job in self.running.items():
                by_origin.setdefault(job.origin, []).append(ProgramRef(pid, attempt))
            self._beats = {origin: Heartbeat(host=self.me, incarnation=self.incarnation, programs=refs)
                           for origin, refs in by_origin.items()}
        out.extend(Send(to=origin, msg=beat) for origin, beat in self._beats.items())
        self._send_progress(now, out)
        for key, (origin, result, resend_at, expires) in list(self._outbox.items()):
            if now >= expires:
                del self._outbox[key]
            elif now >= resend_at:
                out.append(Send(to=origin, msg=result))
                self._outbox[key] = (origin, result, now + self.config.result_resend, expires)
        if self.running:
            self._next_tick = now + self.config.heartbeat_period
        elif self._outbox:
            self._next_tick = now + min(self.config.heartbeat_period, self.config.result_resend)
        else:
            self._next_tick = None
        if self._origins_lost:
            gone = min(self._origins_lost.values()) + self.origin_gone_after
            self._next_tick = gone if self._next_tick is None else min(self._next_tick, gone)

    def _send_progress(self, now: float, out: list[Action]) -> None:
        for (pid, attempt), job in self.running.items():
            if job.progress_new and job.progress is not None:
                self._send_one_progress(pid, attempt, job, now, out)

    def _send_one_progress(self, pid: str, attempt: int, job: _Job, now: float, out: list[Action]) -> None:
        job.progress_new = False
        job.progress_sent_at = now
        out.append(Send(to=job.origin, msg=ProgramProgress(
            program_id=pid, attempt=attempt, host=self.me, fraction=0.0 if job.progress is None else job.progress,
            detail=job.detail)))

    def hand_back(self, now: float, out: list[Action], *, why: str = "") -> int:
        """Shutting down: end every running program with a retryable result so
        each origin places it elsewhere at once. Returns how many. With
        ``why`` (below its battery reserve, ``ramps.core.battery``): only
        teammates' programs, with ``why`` as their error, and it stays open."""
        self.closing = self.closing or not why
        keys = [key for key, job in self.running.items() if not why or job.origin != self.me]
        for pid, attempt in keys:
            out.append(StopProgram(program_id=pid, attempt=attempt))
            self.on_finished(ProgramFinished(program_id=pid, attempt=attempt, ok=False, retryable=True,
                                             error=why or f"{self.me} is shutting down"), now, out)
        return len(keys)

    def unacked_results(self) -> int:
        return len(self._outbox)
