"""A randomized fault campaign in the simulator: ``ramps sim campaign``.

How this works: each run draws a team (3-8 robots of 1-4 cores, some with
background load), one or two origins submitting 5-40 programs, message loss,
and 1-8 random crashes, network cuts, freezes and recoveries of robots that
are not origins, at random times during the workload. With
``load_changes``, robots (origins too) also start or stop busy processes of
their own while programs run, and some workloads checkpoint, so programs are
relocated (``RampsConfig.relocate``) and resumed in the middle of the faults.
After every run it checks the invariants:

* every program of a surviving origin completed, exactly once (no result
  lost, none duplicated);
* a robot that recovered and then published again is back in use: the
  origins' load servers no longer blacklist it.

Runs are seeded (``--seed``), so a failing run can be replayed exactly with
``ramps sim run`` on the scenario it prints.
"""

from __future__ import annotations

import random
import time
from typing import Generic, TypeVar

import msgspec

from ramps.sim.engine import Simulator
from ramps.sim.scenario import FaultKind, FaultSpec, NetworkSpec, ProgramSpec, RobotSpec, Scenario


class CampaignRun(msgspec.Struct, kw_only=True):
    seed: int
    robots: int
    programs: int
    faults: int
    completed: int
    lost: int
    duplicated: int
    not_rejoined: list[str]
    ok: bool
    scenario: Scenario | None = None  # kept for failing runs only
    #: relocations started / abandoned, programs delivered from a resumed attempt
    moves: int = 0
    moves_aborted: int = 0
    resumed: int = 0


#: one run of a campaign: the simulator's ``CampaignRun`` or the testbed's
RunT = TypeVar("RunT")


class CampaignReport(msgspec.Struct, Generic[RunT], kw_only=True):
    """Totals over a campaign's runs (``world``: simulator or testbed)."""

    runs: int
    seed: int
    policy: str
    programs: int
    faults: int
    completed: int
    lost: int
    duplicated: int
    not_rejoined: int
    failed_runs: list[RunT]
    wall_seconds: float
    world: str = "simulator"
    load_changes: bool = False
    moves: int = 0
    moves_aborted: int = 0
    resumed: int = 0


def random_scenario(rng: random.Random, seed: int, policy: str, load_changes: bool = False) -> Scenario:
    n = rng.randint(3, 8)
    robots = [RobotSpec(name=f"r{i}", cores=rng.randint(1, 4), speed=rng.choice([0.5, 1.0, 1.5]),
                        background=rng.choice([0, 0, 0, 2, 8])) for i in range(1, n + 1)]
    origins = ["r1"] if rng.random() < 0.7 else ["r1", "r2"]
    programs = [ProgramSpec(origin=o, count=rng.randint(5, 40), work=rng.uniform(5.0, 60.0),
                            spacing=rng.uniform(0.0, 0.5), at=rng.uniform(0.0, 5.0)) for o in origins]
    others = [r.name for r in robots if r.name not in origins]
    faults: list[FaultSpec] = []
    for robot in others:
        t = rng.uniform(0.0, 10.0)
        for _ in range(rng.randint(0, 2)):
            kind: FaultKind = rng.choice(["crash", "network", "freeze"])
            faults.append(FaultSpec(at=t, robot=robot, kind=kind))
            t += rng.uniform(0.5, 30.0)
            if rng.random() < 0.7:
                faults.append(FaultSpec(at=t, robot=robot, kind="recover"))
                t += rng.uniform(0.5, 30.0)
    if load_changes:  # drawn last: the runs without them stay what they were
        programs = [msgspec.structs.replace(p, checkpoint_every=rng.choice([0.0, 0.0, 1.0, 3.0]))
                    for p in programs]
        for robot in rng.sample([r.name for r in robots], rng.randint(1, min(3, n))):
            t = rng.uniform(0.0, 20.0)
            faults.append(FaultSpec(at=t, robot=robot, kind="load", background=rng.choice([4, 8, 12])))
            if rng.random() < 0.5:
                faults.append(FaultSpec(at=t + rng.uniform(1.0, 30.0), robot=robot, kind="load", background=0))
    return Scenario(name=f"campaign-{seed}", seed=seed, policy=policy, robots=robots, programs=programs,
                    faults=faults, network=NetworkSpec(loss=rng.choice([0.0, 0.0, 0.01, 0.05])), until=1e6)


def run_one(seed: int, policy: str = "ramps", load_changes: bool = False) -> CampaignRun:
    rng = random.Random(seed)
    sc = random_scenario(rng, seed, policy, load_changes)
    sim = Simulator(sc)
    res = sim.run()
    # a robot whose last fault was a recovery, long enough before the end to
    # have published again, must be usable again at every surviving origin
    last: dict[str, FaultSpec] = {}
    for f in sorted(sc.faults, key=lambda f: f.at):
        if f.kind != "load":  # a load change is no fault
            last[f.robot] = f
    origins = {p.origin for p in sc.programs}
    not_rejoined = []
    for robot, f in last.items():
        if f.kind != "recover" or sc.warmup + f.at + 2 * sc.publisher.period + 1.0 > res.end_time:
            continue
        for o in origins:
            if sim.robots[o].node.view.is_blacklisted(robot):
                not_rejoined.append(f"{robot}@{o}")
    ok = res.lost == 0 and res.duplicated == 0 and not not_rejoined
    return CampaignRun(seed=seed, robots=len(sc.robots), programs=sum(p.count for p in sc.programs),
                       faults=len(sc.faults), completed=res.completed, lost=res.lost, duplicated=res.duplicated,
                       not_rejoined=not_rejoined, ok=ok, scenario=None if ok else sc,
                       moves=sum(s.moves for s in res.statistics),
                       moves_aborted=sum(s.moves_aborted for s in res.statistics),
                       resumed=sum(1 for p in res.programs if p.resumed_from is not None and p.deliveries))


def run_campaign(runs: int, seed: int = 0, policy: str = "ramps", progress=None,
                 load_changes: bool = False) -> CampaignReport[CampaignRun]:
    started = time.perf_counter()
    results = []
    for i in range(runs):
        results.append(run_one(seed * 1_000_000 + i, policy, load_changes))
        if progress:
            progress(i + 1, runs)
    return CampaignReport(
        runs=runs, seed=seed, policy=policy, programs=sum(r.programs for r in results),
        faults=sum(r.faults for r in results), completed=sum(r.completed for r in results),
        lost=sum(r.lost for r in results), duplicated=sum(r.duplicated for r in results),
        not_rejoined=sum(len(r.not_rejoined) for r in results), failed_runs=[r for r in results if not r.ok],
        wall_seconds=time.perf_counter() - started, load_changes=load_changes,
        moves=sum(r.moves for r in results), moves_aborted=sum(r.moves_aborted for r in results),
        resumed=sum(r.resumed for r in results),
    )
