"""Deadline workloads: how many programs miss their deadline, against a bound.

How this works: ``generate`` makes one reproducible scenario of the family:
a team of 3-6 robots of mixed cores (1-4) and speeds (0.5-2), two to four
of them origins, each submitting a burst of programs of its own size (10-40
work units) with a deadline of ``slack`` times the program's time on the
fastest robot (slack 1.2-4, drawn per origin). ``run_family`` simulates each
scenario on the same seeds with

- ``ramps``: deadlines told to the origins (``on_miss="run"``),
- ``ramps_ignoring``: the same policy, deadlines only counted,
- ``ramps_fail``: deadlines told, ``on_miss="fail"`` (a program no robot can
  make in time fails at once, and counts as a miss),
- ``round_robin``,

and counts misses: a program with a deadline that was not delivered with a
result by then.

``miss_bound`` is a lower bound on the misses of any placement in this model
(each program run on one robot, at most one core each, a robot's cores
shared), by OR-Tools CP-SAT: choose the programs that finish in time and
where, so that on every robot and for every window [t1, t2] between a
release and a deadline, the programs on time there released at or after t1
and due by t2 need at most ``cores * (t2 - t1)`` core-seconds, and each
fits between its release and its deadline with its communication; maximise
how many. Those conditions hold for any schedule, processor sharing
included, so the misses it leaves are a bound; it is not proven reachable
(a preemptive schedule may need more than sharing gives).
"""

from __future__ import annotations

import random
import statistics
from collections.abc import Sequence

import msgspec

from ramps.core.cost import NetworkEstimate, comm_time
from ramps.sim.engine import simulate
from ramps.sim.scenario import ProgramSpec, RobotSpec, Scenario

#: the policies compared on each scenario: (name, policy, deadlines told, on_miss)
VARIANTS: tuple[tuple[str, str, bool, str], ...] = (
    ("ramps", "ramps", True, "run"),
    ("ramps_ignoring", "ramps", False, "run"),
    ("ramps_fail", "ramps", True, "fail"),
    ("round_robin", "round_robin", False, "run"),
)


class Job(msgspec.Struct, frozen=True, kw_only=True):
    origin: str
    release: float
    deadline: float
    work: float
    payload: int
    result: int


class DeadlineRow(msgspec.Struct, kw_only=True):
    scenario: str
    programs: int
    #: misses per variant (``VARIANTS``' names), and their bound
    misses: dict[str, int]
    makespan: dict[str, float]
    bound: int | None = None
    #: whether CP-SAT proved its maximum (else the bound is from its best bound)
    proven: bool = False


class DeadlineReport(msgspec.Struct, kw_only=True):
    rows: list[DeadlineRow]
    #: misses / programs over the whole family, per variant and for the bound
    miss_ratio: dict[str, float]
    #: the median scenario's miss ratio per variant
    median_ratio: dict[str, float]


def generate(index: int, seed: int = 0) -> Scenario:
    """One reproducible scenario of the family."""
    rng = random.Random(f"{seed}/deadlines/{index}")
    n = rng.randint(3, 6)
    robots = [RobotSpec(name=f"r{i}", cores=rng.choice((1, 2, 2, 4)), speed=rng.choice((0.5, 1.0, 1.0, 1.5, 2.0)))
              for i in range(1, n + 1)]
    fastest = max(r.speed for r in robots)
    origins = rng.sample([r.name for r in robots], rng.randint(2, min(4, n)))
    programs = []
    for origin in origins:
        work = rng.uniform(10.0, 40.0)
        slack = rng.uniform(1.2, 4.0)
        programs.append(ProgramSpec(origin=origin, count=rng.randint(2, 6), work=round(work, 1),
                                    at=round(rng.uniform(0.0, 5.0), 2), spacing=round(rng.uniform(0.0, 2.0), 2),
                                    deadline=round(slack * work / fastest, 2)))
    return Scenario(name=f"deadlines-{index}", seed=rng.getrandbits(32), robots=robots, programs=programs)


def jobs_of(sc: Scenario) -> list[Job]:
    """Every program of ``sc`` with its release and deadline (virtual time, no jitter)."""
    out = []
    for p in sc.programs:
        for i in range(p.count):
            release = max(sc.warmup, sc.warmup + p.at + i * p.spacing)
            if p.deadline is not None:
                out.append(Job(origin=p.origin, release=release, deadline=release + p.deadline, work=p.work,
                               payload=p.payload, result=p.result))
    return out


def miss_bound(sc: Scenario, *, time_limit: float = 2.0) -> tuple[int, bool]:
    """A lower bound on the programs of ``sc`` that miss their deadline
    (see the module's docstring), and whether CP-SAT proved it."""
    from ortools.sat.python import cp_model

    jobs = jobs_of(sc)
    team = sc.team()
    net = NetworkEstimate(latency=sc.network.latency, bandwidth=sc.network.bandwidth)
    scale = 1000  # CP-SAT wants integers: milliseconds and core-milliseconds
    model = cp_model.CpModel()
    x: dict[tuple[int, int], cp_model.IntVar] = {}
    for j, job in enumerate(jobs):
        for r, robot in enumerate(team):
            t = job.work / robot.speed
            if robot.name != job.origin:
                t += comm_time(job.payload, job.result, net)
            if job.release + t <= job.deadline + 1e-9:
                x[j, r] = model.new_bool_var(f"x{j}_{r}")
        model.add(sum(x[j, r] for r in range(len(team)) if (j, r) in x) <= 1)
    starts = sorted({job.release for job in jobs})
    ends = sorted({job.deadline for job in jobs})
    for r, robot in enumerate(team):
        for t1 in starts:
            for t2 in ends:
                inside = [(j, job) for j, job in enumerate(jobs)
                          if (j, r) in x and job.release >= t1 and job.deadline <= t2]
                if not inside or t2 <= t1:
                    continue
                need = sum(round(job.work / robot.speed * scale) * x[j, r] for j, job in inside)
                model.add(need <= int(robot.cores * (t2 - t1) * scale))
    model.maximize(sum(x.values()))
    solver = cp_model.CpSolver()
    solver.parameters.max_time_in_seconds = time_limit
    solver.parameters.num_workers = 1
    solver.parameters.random_seed = 0
    status = solver.solve(model)
    proven = status == cp_model.OPTIMAL
    on_time = solver.objective_value if proven else solver.best_objective_bound
    return len(jobs) - int(on_time + 1e-6), proven


def simulate_variants(sc: Scenario, variants: Sequence[tuple[str, str, bool, str]],
                      sim_seed: int) -> tuple[dict[str, int], dict[str, float]]:
    """(misses, makespan) per variant name of ``sc`` simulated with each
    variant (name, policy, deadlines told, on_miss) on one seed."""
    misses: dict[str, int] = {}
    makespan: dict[str, float] = {}
    for name, policy, told, on_miss in variants:
        run = sc if on_miss == "run" else msgspec.structs.replace(
            sc, programs=[msgspec.structs.replace(p, on_miss=on_miss) for p in sc.programs])
        res = simulate(run, policy=policy, seed=sim_seed, deadlines=told)
        misses[name], makespan[name] = res.deadline_misses, res.makespan
    return misses, makespan


def run_family(count: int = 40, *, seed: int = 0, sim_seed: int = 1, bound: bool = True,
               variants: Sequence[tuple[str, str, bool, str]] = VARIANTS) -> DeadlineReport:
    """Simulate ``count`` scenarios of the family with every variant on the
    same seed, with the CP-SAT bound of each (``bound``)."""
    rows = []
    for i in range(count):
        sc = generate(i, seed)
        misses, makespan = simulate_variants(sc, variants, sim_seed)
        row = DeadlineRow(scenario=sc.name, programs=sum(p.count for p in sc.programs), misses=misses,
                          makespan=makespan)
        if bound:
            row.bound, row.proven = miss_bound(sc)
        rows.append(row)
    names = [v[0] for v in variants] + (["bound"] if bound else [])

    def of(row: DeadlineRow, name: str) -> int:
        return row.bound or 0 if name == "bound" else row.misses[name]

    total = sum(r.programs for r in rows) or 1
    ratio = {n: sum(of(r, n) for r in rows) / total for n in names}
    median = {n: statistics.median(of(r, n) / r.programs for r in rows) if rows else 0.0 for n in names}
    return DeadlineReport(rows=rows, miss_ratio=ratio, median_ratio=median)
