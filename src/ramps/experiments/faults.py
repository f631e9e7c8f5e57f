"""The paper's failure experiments (section 5, Tables 5-10), in the simulator.

How this works: five Raspberry-Pi-class robots, 15 long programs from R1
(long enough that nothing finishes before the failures, as in the paper).
Failures hit R5, R4, R3, R2 either *sequentially* (20 s apart, one run per
repetition, distributions D1..D5 recorded before the first failure and just
before each next one) or *simultaneously* (one scenario per number of failed
robots, the robots failing together). The kind is ``crash``, ``network`` or
``mixed`` (R5 network, R4 crash, R3 network, R2 crash, as in Tables 9-10).

For every failure the report gives the detection time (failure to the first
time the origin writes the robot off), the time until every program that
was running there runs again elsewhere (accepted by a new host), and the
lost and duplicated results of the run. ``FaultPlan`` is the experiment
description; the testbed runs the same plans on real processes.
"""

from __future__ import annotations

import statistics
from typing import Literal, cast

import msgspec

from ramps.core.config import RampsConfig
from ramps.experiments.metrics import classify_counts
from ramps.sim.engine import Simulator
from ramps.sim.scenario import FaultSpec, NetworkSpec, ProgramSpec, RobotSpec, Scenario

ROBOTS = ["R1", "R2", "R3", "R4", "R5"]
ORDER = ["R5", "R4", "R3", "R2"]
KINDS = ("crash", "network", "mixed")
#: what one failure does to a robot (``mixed`` plans alternate the two)
FailureKind = Literal["crash", "network"]
MIXED: dict[str, FailureKind] = {"R5": "network", "R4": "crash", "R3": "network", "R2": "crash"}


class FaultPlan(msgspec.Struct, frozen=True, kw_only=True):
    """One run: which robots fail, how, and when (seconds after the submit)."""

    name: str
    mode: str  # sequential | simultaneous
    kind: str  # crash | network | mixed
    failures: list[tuple[float, str, FailureKind]]  # (at, robot, kind)
    #: when to record distributions (seconds after the submit), with labels
    snapshots: list[tuple[str, float]]


def plans(mode: str, kind: str, *, first: float = 20.0, gap: float = 20.0) -> list[FaultPlan]:
    if kind not in KINDS:
        raise ValueError(f"unknown failure kind {kind!r}; choose one of {', '.join(KINDS)}")

    def how(robot: str) -> FailureKind:
        return MIXED[robot] if kind == "mixed" else cast(FailureKind, kind)  # crash or network, checked above

    if mode == "sequential":
        fails = [(first + i * gap, r, how(r)) for i, r in enumerate(ORDER)]
        snaps = [("D1", first - 1.0)] + [(f"D{i + 2}", first + (i + 1) * gap - 1.0) for i in range(len(ORDER))]
        return [FaultPlan(name=f"sequential {kind}", mode=mode, kind=kind, failures=fails, snapshots=snaps)]
    if mode == "simultaneous":
        out = []
        for k in range(1, len(ORDER) + 1):
            robots = ORDER[:k]
            out.append(FaultPlan(name=f"simultaneous {kind}: {','.join(sorted(robots))}", mode=mode, kind=kind,
                                 failures=[(first, r, how(r)) for r in robots],
                                 snapshots=[("before", first - 1.0), ("after", first + gap - 1.0)]))
        return out
    raise ValueError(f"unknown mode {mode!r}; choose sequential or simultaneous")


class FailureRecord(msgspec.Struct, kw_only=True):
    robot: str
    kind: str
    at: float
    displaced: int
    #: seconds from the failure to the origin writing the robot off (None: never)
    detection: float | None
    #: seconds from the failure until every displaced program ran again
    recovery: float | None


class FaultRun(msgspec.Struct, kw_only=True):
    plan: str
    seed: int
    distributions: dict[str, dict[str, int]]
    classifications: dict[str, str]
    failures: list[FailureRecord]
    completed: int
    lost: int
    duplicated: int
    makespan: float


class FaultReport(msgspec.Struct, kw_only=True):
    experiment: str
    policy: str
    mode: str
    kind: str
    runs: list[FaultRun]
    summary: dict
    #: simulator or testbed
    world: str = "simulator"
    #: seconds from the submit to the first failure, and between failures
    first: float = 20.0
    gap: float = 20.0


def scenario_for(plan: FaultPlan, *, seed: int, policy: str, work: float = 300.0) -> Scenario:
    paper = policy == "paper"
    return Scenario(
        name=plan.name, seed=seed, policy=policy,
        robots=[RobotSpec(name=r, cores=4, speed=1.0) for r in ROBOTS],
        programs=[ProgramSpec(count=15, work=work, payload=1000, result=1000, origin="R1", spacing=0.05,
                              jitter=0.02)],
        faults=[FaultSpec(at=at, robot=r, kind=k) for at, r, k in plan.failures],
        # the prototype had connection timeouts and heartbeats only (ROS 1)
        network=NetworkSpec(liveliness=not paper),
        config=RampsConfig.paper() if paper else RampsConfig(),
    )


def run_plan(plan: FaultPlan, *, seed: int, policy: str = "ramps") -> FaultRun:
    sc = scenario_for(plan, seed=seed, policy=policy)
    sim = Simulator(sc, trace=True, snapshots=[t for _, t in plan.snapshots])
    res = sim.run()
    w = sc.warmup
    dists, classes = {}, {}
    failed_by: dict[str, float] = {}
    for label, t in plan.snapshots:
        counts = res.snapshots[f"{t:g}"]
        for at, robot, _ in plan.failures:
            if at <= t:
                failed_by[robot] = at
        alive = {r: counts[r] for r in ROBOTS if r not in failed_by or failed_by[r] > t}
        dists[label] = alive
        classes[label] = classify_counts(list(alive.values()))
    records = []
    for at, robot, kind in plan.failures:
        done = {p.program_id for p in res.programs if p.delivered_at is not None and p.delivered_at < w + at}
        records.append(_failure_record(res.trace, w + at, robot, kind, done))
    return FaultRun(plan=plan.name, seed=seed, distributions=dists, classifications=classes, failures=records,
                    completed=res.completed, lost=res.lost, duplicated=res.duplicated, makespan=res.makespan)


def _failure_record(trace, t_fail: float, robot: str, kind: str, done_before: set[str]) -> FailureRecord:
    """``done_before``: programs delivered before the failure (never displaced).
    A program the failed robot itself delivers after the failure was not
    displaced either: it ended there as the failure came (on real processes
    the failure's moment is taken just before it is injected, and a result
    already on its way still arrives)."""
    host_at: dict[str, str] = {}
    detection = None
    again: dict[str, float] = {}
    ended_there: set[str] = set()
    for e in trace:
        if e.t < t_fail:
            if e.what == "accepted":
                host_at[e.program_id] = e.other
            continue
        if detection is None and e.what in ("failed", "blacklisted") and e.other == robot:
            detection = e.t - t_fail
        if e.what == "accepted" and e.other != robot:
            again.setdefault(e.program_id, e.t - t_fail)
        if e.what == "delivered" and e.other == robot:
            ended_there.add(e.program_id)
    displaced = {p for p, h in host_at.items() if h == robot and p not in done_before and p not in ended_there}
    again = {p: t for p, t in again.items() if p in displaced}
    recovery = max(again.values()) if displaced and len(again) == len(displaced) else (0.0 if not displaced else None)
    return FailureRecord(robot=robot, kind=kind, at=t_fail, displaced=len(displaced), detection=detection,
                         recovery=recovery)


def run_fault_experiment(mode: str, kind: str, *, policy: str = "ramps", runs: int = 3, seed: int = 0,
                         runner=None, first: float = 20.0, gap: float = 20.0, world: str = "simulator",
                         progress=None) -> FaultReport:
    """Every plan of ``mode``/``kind``, ``runs`` times each. ``runner(plan,
    seed=, policy=)`` runs one plan and returns a ``FaultRun``: the simulator's
    ``run_plan`` by default, the testbed's for ``ramps testbed experiment``."""
    runner = runner or run_plan
    todo = [(plan, seed * 1000 + k) for plan in plans(mode, kind, first=first, gap=gap) for k in range(runs)]
    out = []
    for i, (plan, s) in enumerate(todo):
        out.append(runner(plan, seed=s, policy=policy))
        if progress:
            progress(i + 1, len(todo), out[-1])
    return FaultReport(experiment="faults", policy=policy, mode=mode, kind=kind, runs=out, summary=summarize(out),
                       world=world, first=first, gap=gap)


def summarize(out: list[FaultRun]) -> dict:
    det = [f.detection for r in out for f in r.failures if f.detection is not None]
    rec = [f.recovery for r in out for f in r.failures if f.recovery is not None]
    # recovery beyond detection: back-off plus placement, bounded by backoff_max plus a little
    after = [f.recovery - f.detection for r in out for f in r.failures
             if f.recovery is not None and f.detection is not None and f.displaced]
    classes = [c for r in out for label, c in r.classifications.items() if label not in ("D1", "before")]
    return {
        "runs": len(out), "lost": sum(r.lost for r in out), "duplicated": sum(r.duplicated for r in out),
        "completed": sum(r.completed for r in out), "programs": 15 * len(out),
        "detection_median_s": statistics.median(det) if det else None,
        "detection_max_s": max(det) if det else None,
        "recovery_median_s": statistics.median(rec) if rec else None,
        "recovery_max_s": max(rec) if rec else None,
        "recovery_after_detection_max_s": max(after) if after else None,
        "undetected_failures": sum(1 for r in out for f in r.failures if f.detection is None),
        "distributions_after_failures": len(classes),
        "optimal_or_near_after_failures": sum(1 for c in classes if c != "non_optimal"),
    }
