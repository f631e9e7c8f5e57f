"""Load that comes after placement, and relocation, in the simulator: ``ramps sim relocation``.

How this works: a team of ``robots`` identical robots (4 cores each); robot
``r1`` submits ``programs`` programs of ``work`` units at once, and at
``load_at`` seconds one robot that runs some of them (``loaded``) starts
``busy`` CPU-bound processes of its own (a heavy job of the robot's own
software, after placement). Each seed runs four variants on the same team:
relocation off, on (restart from the parameters), on with programs that
checkpoint every ``checkpoint_every`` seconds, and round robin, and prints
their makespans beside the *hindsight optimum*: the best static
distribution of the programs over the robots by someone who knew when the
load would come (``hindsight_optimum``, processor sharing, no transfer
times), the bound every variant is divided by.

Rules: seeded and deterministic like every simulator experiment; the same
arguments print the same figures.
"""

from __future__ import annotations

import itertools
import statistics
import time

import msgspec

from ramps.core.config import RampsConfig
from ramps.sim.engine import simulate
from ramps.sim.scenario import FaultSpec, ProgramSpec, RobotSpec, Scenario

VARIANTS = ("relocation off", "relocation", "relocation + checkpoints", "round robin")


class RelocationRun(msgspec.Struct, kw_only=True):
    seed: int
    variant: str
    makespan: float
    #: makespan / hindsight optimum
    ratio: float
    moves: int
    moves_aborted: int
    resumed: int
    lost: int
    duplicated: int
    distribution: dict[str, int]


class RelocationReport(msgspec.Struct, kw_only=True):
    robots: int
    cores: int
    programs: int
    work: float
    loaded: str
    load_at: float
    busy: int
    checkpoint_every: float
    hindsight_optimum: float
    #: the static distribution that reaches it
    optimum_distribution: list[int]
    runs: list[RelocationRun]
    #: variant -> median makespan / hindsight optimum over the seeds
    median_ratio: dict[str, float]
    wall_seconds: float


def finish_time(n: int, work: float, cores: int, speed: float, busy: int, load_at: float) -> float:
    """When ``n`` identical programs of ``work`` units started together at 0
    end on one robot that gets ``busy`` busy processes at ``load_at``
    (processor sharing: each task runs at speed * min(1, cores / tasks))."""
    if n == 0:
        return 0.0
    rate = speed * min(1.0, cores / n)
    if rate * load_at >= work:
        return work / rate
    later = speed * min(1.0, cores / (n + busy))
    return load_at + (work - rate * load_at) / later


def hindsight_optimum(robots: int, cores: int, programs: int, work: float, loaded: int, busy: int,
                      load_at: float, speed: float = 1.0) -> tuple[float, list[int]]:
    """The best makespan of a static distribution knowing the load to come,
    and that distribution (robot ``loaded``, 0-based, gets the busy processes)."""
    best, best_split = float("inf"), [programs] + [0] * (robots - 1)
    for cuts in itertools.combinations(range(programs + robots - 1), robots - 1):
        split, prev = [], -1
        for c in cuts + (programs + robots - 1,):
            split.append(c - prev - 1)
            prev = c
        t = max(finish_time(n, work, cores, speed, busy if i == loaded else 0, load_at)
                for i, n in enumerate(split))
        if t < best - 1e-9:
            best, best_split = t, split
    return best, best_split


def scenario(variant: str, *, robots: int, cores: int, programs: int, work: float, loaded: str, busy: int,
             load_at: float, checkpoint_every: float, seed: int) -> Scenario:
    config = RampsConfig(relocate=variant != "relocation off")
    every = checkpoint_every if variant == "relocation + checkpoints" else 0.0
    return Scenario(
        name=f"relocation: {variant}", seed=seed, policy="round_robin" if variant == "round robin" else "ramps",
        robots=[RobotSpec(name="r{i}", cores=cores, count=robots)],
        programs=[ProgramSpec(origin="r1", count=programs, work=work, checkpoint_every=every)],
        faults=[FaultSpec(at=load_at, robot=loaded, kind="load", background=busy)],
        config=config,
    )


def run_relocation(*, robots: int = 3, cores: int = 4, programs: int = 8, work: float = 60.0, loaded: str = "r1",
                   busy: int = 8, load_at: float = 10.0, checkpoint_every: float = 2.0, seeds: int = 5,
                   seed: int = 0) -> RelocationReport:
    started = time.perf_counter()
    names = [f"r{i}" for i in range(1, robots + 1)]
    if loaded not in names:
        raise ValueError(f"loaded robot {loaded!r} is not in the team ({', '.join(names)})")
    opt, split = hindsight_optimum(robots, cores, programs, work, names.index(loaded), busy, load_at)
    runs = []
    for s in range(seed, seed + seeds):
        for variant in VARIANTS:
            sc = scenario(variant, robots=robots, cores=cores, programs=programs, work=work, loaded=loaded,
                          busy=busy, load_at=load_at, checkpoint_every=checkpoint_every, seed=s)
            res = simulate(sc)
            runs.append(RelocationRun(
                seed=s, variant=variant, makespan=res.makespan, ratio=res.makespan / opt,
                moves=sum(st.moves for st in res.statistics), moves_aborted=sum(st.moves_aborted
                                                                               for st in res.statistics),
                resumed=sum(1 for p in res.programs if p.resumed_from is not None), lost=res.lost,
                duplicated=res.duplicated, distribution=res.distribution))
    med = {v: statistics.median(r.ratio for r in runs if r.variant == v) for v in VARIANTS}
    return RelocationReport(robots=robots, cores=cores, programs=programs, work=work, loaded=loaded,
                            load_at=load_at, busy=busy, checkpoint_every=checkpoint_every, hindsight_optimum=opt,
                            optimum_distribution=split, runs=runs, median_ratio=med,
                            wall_seconds=time.perf_counter() - started)


class CampaignComparison(msgspec.Struct, kw_only=True):
    """Relocation on against off on the fault campaign's scenarios with load changes."""

    runs: int
    seed: int
    #: makespan with relocation / without, per run, sorted
    ratios: list[float]
    median: float
    better: int
    worse: int
    moves: int
    lost: int
    duplicated: int
    wall_seconds: float


def compare_on_campaign(runs: int, seed: int = 0) -> CampaignComparison:
    """Run each of ``runs`` campaign scenarios (``ramps sim campaign
    --load-changes``, same seeds) with relocation on and off."""
    import random

    from ramps.experiments.campaign import random_scenario

    started = time.perf_counter()
    ratios, moves, lost, dup = [], 0, 0, 0
    for i in range(runs):
        s = seed * 1_000_000 + i
        sc = random_scenario(random.Random(s), s, "ramps", True)
        on = simulate(sc)
        off = simulate(msgspec.structs.replace(sc, config=msgspec.structs.replace(sc.config, relocate=False)))
        ratios.append(on.makespan / off.makespan if off.makespan > 0 else 1.0)
        moves += sum(st.moves for st in on.statistics)
        lost += on.lost + off.lost
        dup += on.duplicated + off.duplicated
    ratios.sort()
    return CampaignComparison(runs=runs, seed=seed, ratios=ratios, median=statistics.median(ratios),
                              better=sum(r < 0.999 for r in ratios), worse=sum(r > 1.001 for r in ratios),
                              moves=moves, lost=lost, duplicated=dup, wall_seconds=time.perf_counter() - started)
