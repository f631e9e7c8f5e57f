"""The paper's load-distribution experiments (section 4), in the simulator.

How this works: each configuration (team size, number of programs, loaded
robots) is run ``runs`` times with different seeds; every run simulates the
chosen policy, round robin and a single robot on the same scenario and seed,
so the three are compared on identical conditions. A configuration is five
Raspberry-Pi-3-class robots (4 cores, speed 1.0) and identical route-planning
programs of 53 work units (53 s on an idle Pi 3 core, as measured by the
paper) submitted from R1 in a quick burst (the prototype started each
autonomous program as its own ROS node, a few tens of milliseconds apart).

* ``unloaded``: teams of 2-5 robots, 5-30 programs (Table 3, Figs 3-4);
  72 distributions with 3 runs.
* ``loaded``: 5 robots of which the last 1-4 run 8 CPU-bound processes
  (the paper's ``stress``), 5-30 programs (Table 4, Figs 5-6), with the best
  makespan achievable under the same model printed beside each result.
"""

from __future__ import annotations

import statistics
from typing import Callable

import msgspec

from ramps.core.config import RampsConfig
from ramps.experiments.metrics import (
    NEAR_OPTIMAL,
    NON_OPTIMAL,
    OPTIMAL,
    Machine,
    classify,
    free_core_violation,
    optimal_allocation,
)
from ramps.core.cost import NetworkEstimate, comm_time
from ramps.sim.engine import simulate
from ramps.sim.scenario import NetworkSpec, ProgramSpec, PublisherSpec, RobotSpec, Scenario

EXPERIMENTS = ("unloaded", "loaded")
TEAM_SIZES = (2, 3, 4, 5)
PROGRAM_COUNTS = (5, 10, 15, 20, 25, 30)
LOADED_COUNTS = (1, 2, 3, 4)

#: the paper's measured runtimes on 5 robots (the paper's section 4: single robot, round robin and RAMPs), seconds
PAPER_5_ROBOTS = {
    "single": {5: 110, 10: 222, 15: 335, 20: 449, 25: 564, 30: 670},
    "round_robin": {5: 53, 10: 54, 15: 55, 20: 58, 25: 71, 30: 85},
    "ramps": {5: 53, 10: 58, 15: 59, 20: 73, 25: 84, 30: 100},
}


class PaperSetup(msgspec.Struct, frozen=True, kw_only=True):
    """Everything about the paper's testbed the experiments assume."""

    work: float = 53.0
    cores: int = 4
    speed: float = 1.0
    payload: int = 1000
    result: int = 1000
    #: seconds between two autonomous programs starting on the origin
    spacing: float = 0.05
    jitter: float = 0.02
    #: CPU-bound processes on a loaded robot
    stress: int = 8
    network: NetworkSpec = NetworkSpec()
    publisher: PublisherSpec = PublisherSpec()
    config: RampsConfig = RampsConfig()


class RunRecord(msgspec.Struct, kw_only=True):
    seed: int
    distribution: list[int]
    classification: str
    makespan: float
    round_robin_makespan: float
    single_makespan: float
    speedup: float
    ratio_to_round_robin: float
    round_robin_distribution: list[int]
    optimum_makespan: float
    ratio_to_optimum: float
    loaded_robot_used_while_core_free: bool
    completed: int
    lost: int
    duplicated: int


class ConfigRecord(msgspec.Struct, kw_only=True):
    team_size: int
    programs: int
    loaded: int
    #: U for an unloaded robot, L for a loaded one, R1 first (Table 4's key)
    pattern: str
    optimal_distribution: list[int]
    runs: list[RunRecord]
    median_makespan: float
    median_round_robin: float
    median_single: float
    mean_distribution: list[float]
    paper: dict[str, float] = {}


class Summary(msgspec.Struct, kw_only=True):
    distributions: int
    optimal: int
    near_optimal: int
    non_optimal: int
    optimal_share: float
    optimal_or_near_share: float
    worst_ratio_to_round_robin: float
    worst_ratio_to_optimum: float
    free_core_violations: int
    lost: int
    duplicated: int


class ExperimentReport(msgspec.Struct, kw_only=True):
    experiment: str
    policy: str
    runs: int
    seed: int
    setup: PaperSetup
    configs: list[ConfigRecord]
    summary: Summary
    wall_seconds: float = 0.0


def team_for(size: int, loaded: int, setup: PaperSetup) -> list[RobotSpec]:
    return [
        RobotSpec(name=f"R{i}", cores=setup.cores, speed=setup.speed,
                  background=setup.stress if i > size - loaded else 0)
        for i in range(1, size + 1)
    ]


def scenario_for(size: int, programs: int, loaded: int, setup: PaperSetup, seed: int) -> Scenario:
    return Scenario(
        name=f"paper-{size}r-{programs}p-{loaded}l",
        seed=seed,
        robots=team_for(size, loaded, setup),
        programs=[ProgramSpec(program="route_plan", count=programs, work=setup.work, payload=setup.payload,
                              result=setup.result, origin="R1", spacing=setup.spacing, jitter=setup.jitter)],
        network=setup.network,
        publisher=setup.publisher,
        config=setup.config,
    )


def run_config(size: int, programs: int, loaded: int, *, policy: str, runs: int, seed: int,
               setup: PaperSetup) -> ConfigRecord:
    team = [Machine(r.cores, r.speed, r.background) for r in team_for(size, loaded, setup)]
    opt_counts, opt_model = optimal_allocation(programs, team, setup.work)
    t_comm = comm_time(setup.payload, setup.result,
                       NetworkEstimate(latency=setup.network.latency, bandwidth=setup.network.bandwidth))
    optimum = opt_model + t_comm
    names = [f"R{i}" for i in range(1, size + 1)]
    records = []
    for k in range(runs):
        run_seed = seed * 1_000_003 + size * 10_007 + programs * 101 + loaded * 7 + k
        sc = scenario_for(size, programs, loaded, setup, run_seed)
        res = simulate(sc, policy=policy)
        rr = simulate(sc, policy="round_robin")
        single = simulate(sc, policy="local_only")
        dist = [res.distribution[n] for n in names]
        records.append(RunRecord(
            seed=run_seed, distribution=dist, classification=classify(dist, team, setup.work),
            makespan=res.makespan, round_robin_makespan=rr.makespan, single_makespan=single.makespan,
            speedup=single.makespan / res.makespan, ratio_to_round_robin=res.makespan / rr.makespan,
            round_robin_distribution=[rr.distribution[n] for n in names],
            optimum_makespan=optimum, ratio_to_optimum=res.makespan / optimum,
            loaded_robot_used_while_core_free=free_core_violation(dist, team),
            completed=res.completed, lost=res.lost, duplicated=res.duplicated,
        ))
    paper = {}
    if size == 5 and loaded == 0:
        paper = {key: float(table[programs]) for key, table in PAPER_5_ROBOTS.items()}
    return ConfigRecord(
        team_size=size, programs=programs, loaded=loaded,
        pattern="".join("L" if m.background else "U" for m in team),
        optimal_distribution=opt_counts, runs=records,
        median_makespan=statistics.median(r.makespan for r in records),
        median_round_robin=statistics.median(r.round_robin_makespan for r in records),
        median_single=statistics.median(r.single_makespan for r in records),
        mean_distribution=[round(statistics.fmean(r.distribution[i] for r in records), 2) for i in range(size)],
        paper=paper,
    )


def configurations(experiment: str) -> list[tuple[int, int, int]]:
    if experiment == "unloaded":
        return [(size, n, 0) for n in PROGRAM_COUNTS for size in reversed(TEAM_SIZES)]
    if experiment == "loaded":
        return [(5, n, loaded) for n in PROGRAM_COUNTS for loaded in LOADED_COUNTS]
    raise ValueError(f"unknown experiment {experiment!r}; choose one of {', '.join(EXPERIMENTS)}")


def run_experiment(experiment: str, *, policy: str = "ramps", runs: int = 3, seed: int = 0,
                   setup: PaperSetup | None = None,
                   progress: Callable[[int, int], None] | None = None) -> ExperimentReport:
    """Run every configuration of one experiment; ``progress(done, total)``."""
    import time

    setup = setup or PaperSetup()
    if runs < 1:
        raise ValueError("runs must be >= 1")
    started = time.perf_counter()
    configs = configurations(experiment)
    out = []
    for i, (size, n, loaded) in enumerate(configs):
        out.append(run_config(size, n, loaded, policy=policy, runs=runs, seed=seed, setup=setup))
        if progress:
            progress(i + 1, len(configs))
    report = ExperimentReport(experiment=experiment, policy=policy, runs=runs, seed=seed, setup=setup,
                              configs=out, summary=summarise(out))
    report.wall_seconds = time.perf_counter() - started
    return report


def summarise(configs: list[ConfigRecord]) -> Summary:
    runs = [r for c in configs for r in c.runs]
    n = len(runs)
    count = {k: sum(1 for r in runs if r.classification == k) for k in (OPTIMAL, NEAR_OPTIMAL, NON_OPTIMAL)}
    return Summary(
        distributions=n, optimal=count[OPTIMAL], near_optimal=count[NEAR_OPTIMAL], non_optimal=count[NON_OPTIMAL],
        optimal_share=count[OPTIMAL] / n if n else 0.0,
        optimal_or_near_share=(count[OPTIMAL] + count[NEAR_OPTIMAL]) / n if n else 0.0,
        worst_ratio_to_round_robin=max((c.median_makespan / c.median_round_robin for c in configs), default=0.0),
        worst_ratio_to_optimum=max((r.ratio_to_optimum for r in runs), default=0.0),
        free_core_violations=sum(1 for r in runs if r.loaded_robot_used_while_core_free),
        lost=sum(r.lost for r in runs), duplicated=sum(r.duplicated for r in runs),
    )
