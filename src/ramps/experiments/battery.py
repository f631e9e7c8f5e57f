"""Low batteries against an exact optimum: ``ramps sim battery``.

How this works: ``generate`` makes one reproducible scenario of the family:
a team of 3-5 robots of mixed cores (1-4) and speeds (0.5-2), every one
with a battery, two or three of them origins submitting a burst of 2-4
programs each (10-40 work units, at most 12 programs in all, checkpointing
every 2 s), and what makes it hard, one or more of:

* a robot below its reserve from the start (charge 0.05-0.19, reserve 0.2);
* a robot whose charge drops below its reserve mid-run (a ``battery``
  fault 1-15 s after the first program);
* a robot that is no origin crashing mid-run (a failure).

Each scenario is simulated on the same seed with ``ramps`` (the reserve
on, the default), ``ramps_without`` (the same policy with
``battery_reserve = 0``: batteries ignored) and ``round_robin`` (the
reserve on: its hosts refuse and hand back as any host does), and compared
with the exact ``optimum`` under the same model. ``ramps_full`` is the
placement alone: the same team and programs with every battery full and no
drop (crashes kept), against that scenario's own optimum, so what
``ramps`` loses beyond it is what the batteries cost it.

``optimum``: the shortest makespan (last delivery after the first
release) over every placement of the programs, each on one robot from its
release, never moved, sharing that robot's cores with the programs placed
there (processor sharing), with ``comm_time`` for programs off their
origin; where a robot below its reserve runs no teammate's program: a
program of another origin placed on a robot that is low from the start is
not allowed, and on one that drops (or crashes) at ``t`` it must end
before ``t``. It knows every drop and crash in advance (no online
placement can); a schedule that moves programs (ramps hands them back and
they resume from their checkpoints) is outside its model and may end
earlier. Exact for this model by dynamic programming over subsets (as
``ramps.experiments.deadlines_optimum``): ``robots * 3**programs`` steps,
so at most 12 programs.

``violations`` counts the programs a variant let run on a robot below its
reserve for another origin: delivered from a robot low from the start, or
from one that dropped before they were delivered.
"""

from __future__ import annotations

import math
import random
import statistics
from collections.abc import Callable, Sequence

import msgspec
import numpy as np

from ramps.core.cost import NetworkEstimate
from ramps.experiments.deadlines_optimum import shared_ends
from ramps.sim.engine import simulate
from ramps.sim.results import SimResult
from ramps.sim.scenario import FaultSpec, ProgramSpec, RobotSpec, Scenario

#: the variants compared on each scenario: (name, policy, battery_reserve)
VARIANTS: tuple[tuple[str, str, float], ...] = (
    ("ramps", "ramps", 0.2),
    ("ramps_without", "ramps", 0.0),
    ("round_robin", "round_robin", 0.2),
)
#: the placement alone: ``full(sc)`` against its own optimum (module docstring)
FULL = "ramps_full"
MAX_PROGRAMS = 12
_EPS = 1e-9


class Job(msgspec.Struct, frozen=True, kw_only=True):
    origin: str
    release: float
    work: float
    payload: int
    result: int


class BatteryRow(msgspec.Struct, kw_only=True):
    scenario: str
    robots: int
    programs: int
    #: what happens: "low" (a robot below its reserve from the start), "drop", "crash"
    events: list[str]
    optimum: float
    #: per variant: makespan, its ratio to the optimum, and its violations
    makespan: dict[str, float]
    ratio: dict[str, float]
    violations: dict[str, int]
    lost: dict[str, int]
    duplicated: dict[str, int]


class BatteryReport(msgspec.Struct, kw_only=True):
    rows: list[BatteryRow]
    #: per variant, over the rows: median, 90th percentile and worst ratio to
    #: the optimum, scenarios within 3% / 10%, programs run on low robots
    #: for teammates, lost and duplicated
    summary: dict[str, dict[str, float]]


def generate(index: int, seed: int = 0) -> Scenario:
    """One reproducible scenario of the family (module docstring)."""
    rng = random.Random(f"{seed}/battery/{index}")
    n = rng.randint(3, 5)
    robots = [RobotSpec(name=f"r{i}", cores=rng.choice((1, 2, 2, 4)), speed=rng.choice((0.5, 1.0, 1.0, 1.5, 2.0)),
                        battery=round(rng.uniform(0.3, 1.0), 2)) for i in range(1, n + 1)]
    names = [r.name for r in robots]
    origins = rng.sample(names, rng.randint(2, min(3, n)))
    programs, left = [], MAX_PROGRAMS
    for k, origin in enumerate(origins):
        count = min(left - 2 * (len(origins) - k - 1), rng.randint(2, 4))
        left -= count
        programs.append(ProgramSpec(origin=origin, count=count, work=round(rng.uniform(10.0, 40.0), 1),
                                    at=round(rng.uniform(0.0, 3.0), 2), spacing=round(rng.uniform(0.0, 1.0), 2),
                                    checkpoint_every=2.0, checkpoint_size=1000))
    events: list[str] = []
    while not events:
        events = [e for e, p in (("low", 0.5), ("drop", 0.6), ("crash", 0.3)) if rng.random() < p]
    faults = []
    if "low" in events:
        i = rng.randrange(n)
        robots[i] = msgspec.structs.replace(robots[i], battery=round(rng.uniform(0.05, 0.19), 2))
    if "drop" in events:
        target = rng.choice([r for r in names if (robots[names.index(r)].battery or 0.0) >= 0.3])
        faults.append(FaultSpec(at=round(rng.uniform(1.0, 15.0), 2), robot=target, kind="battery", charge=0.1))
    if "crash" in events:
        spare = [r for r in names if r not in origins and all(f.robot != r for f in faults)]
        if spare:
            faults.append(FaultSpec(at=round(rng.uniform(1.0, 15.0), 2), robot=rng.choice(spare), kind="crash"))
        else:
            events.remove("crash")
            if not events:
                events = ["none"]
    return Scenario(name=f"battery-{index}-{'+'.join(events)}", seed=rng.getrandbits(32), robots=robots,
                    programs=programs, faults=faults)


def full(sc: Scenario) -> Scenario:
    """``sc`` with every battery full and no battery fault (crashes kept)."""
    return msgspec.structs.replace(sc, robots=[msgspec.structs.replace(r, battery=1.0) for r in sc.robots],
                                   faults=[f for f in sc.faults if f.kind != "battery"])


def jobs_of(sc: Scenario) -> list[Job]:
    """Every program of ``sc`` with its release (virtual time, no jitter)."""
    return [Job(origin=p.origin, release=sc.warmup + p.at + i * p.spacing, work=p.work, payload=p.payload,
                result=p.result) for p in sc.programs for i in range(p.count)]


def hosting_until(sc: Scenario) -> dict[str, float]:
    """Until when each robot may run a teammate's program: -inf for one
    below its reserve from the start, the time of its drop or crash, else inf."""
    reserve = sc.config.battery_reserve
    until = {r.name: (-math.inf if r.battery is not None and r.battery < reserve else math.inf) for r in sc.team()}
    for f in sc.faults:
        if f.kind == "crash" or (f.kind == "battery" and f.charge is not None and f.charge < reserve):
            until[f.robot] = min(until[f.robot], sc.warmup + f.at)
    return until


def subset_costs(jobs: list[Job], robot: RobotSpec, until: float, net: NetworkEstimate) -> np.ndarray:
    """For every subset of ``jobs`` (a bit mask) on ``robot``, its last
    delivery; inf where a teammate's program would still run at ``until``."""
    n = len(jobs)
    last = np.zeros(1 << n, dtype=np.float64)
    own = [j.origin == robot.name for j in jobs]
    comm_in = [0.0 if own[k] else 2 * net.latency + jobs[k].payload / net.bandwidth for k in range(n)]
    comm_out = [0.0 if own[k] else net.latency + jobs[k].result / net.bandwidth for k in range(n)]
    for mask in range(1, 1 << n):
        idx = [k for k in range(n) if mask >> k & 1]
        if until == -math.inf and not all(own[k] for k in idx):
            last[mask] = math.inf
            continue
        ends = shared_ends([jobs[k].release + comm_in[k] for k in idx], [jobs[k].work for k in idx],
                           robot.speed, robot.cores)
        if any(e > until + _EPS for e, k in zip(ends, idx) if not own[k]):
            last[mask] = math.inf
            continue
        last[mask] = max(e + comm_out[k] for e, k in zip(ends, idx))
    return last


def optimum(sc: Scenario) -> float:
    """The shortest makespan of ``sc`` in this module's model (its docstring)."""
    jobs = jobs_of(sc)
    n = len(jobs)
    if not 0 < n <= MAX_PROGRAMS:
        raise ValueError(f"{n} programs: the exact search takes 1 to {MAX_PROGRAMS}")
    net = NetworkEstimate(latency=sc.network.latency, bandwidth=sc.network.bandwidth)
    until = hosting_until(sc)
    masks = np.arange(1 << n, dtype=np.int64)
    best = np.where(masks == 0, 0.0, math.inf)
    for robot in sc.team():
        cost = subset_costs(jobs, robot, until[robot.name], net)
        new = best.copy()  # the robot runs nothing
        for sub in range(1, 1 << n):
            if not math.isfinite(cost[sub]):
                continue
            sel = masks[(masks & sub) == sub]
            f = np.maximum(best[sel ^ sub], cost[sub])
            new[sel] = np.minimum(new[sel], f)
        best = new
    return float(best[-1]) - min(j.release for j in jobs)


def violations(sc: Scenario, res: SimResult) -> int:
    """Programs ``res`` delivered from a robot below its reserve, for another
    origin (``hosting_until``: low from the start, or dropped before)."""
    until = hosting_until(sc)
    crashed = {f.robot for f in sc.faults if f.kind == "crash"}
    return sum(1 for p in res.programs if p.host and p.host != p.origin and p.host not in crashed
               and p.delivered_at is not None and p.delivered_at > until[p.host])


def run_family(count: int = 200, *, seed: int = 0, sim_seed: int = 1,
               variants: Sequence[tuple[str, str, float]] = VARIANTS,
               progress: Callable[[int, int], None] | None = None) -> BatteryReport:
    """``count`` scenarios of the family, each simulated with every variant
    on one seed and compared with its ``optimum``."""
    rows = []
    names = [v[0] for v in variants]
    for i in range(count):
        sc = generate(i, seed)
        best = optimum(sc)
        row = BatteryRow(scenario=sc.name, robots=len(sc.robots), programs=len(jobs_of(sc)),
                         events=sc.name.split("-", 2)[2].split("+"), optimum=round(best, 3), makespan={},
                         ratio={}, violations={}, lost={}, duplicated={})
        for name, policy, reserve in variants:
            run = msgspec.structs.replace(sc, config=msgspec.structs.replace(sc.config, battery_reserve=reserve))
            res = simulate(run, policy=policy, seed=sim_seed)
            row.makespan[name] = round(res.makespan, 3)
            row.ratio[name] = round(res.makespan / best, 4) if best > 0 else 1.0
            row.violations[name] = violations(sc, res)
            row.lost[name], row.duplicated[name] = res.lost, res.duplicated
        alone = full(sc)
        res = simulate(alone, policy="ramps", seed=sim_seed)
        row.makespan[FULL] = round(res.makespan, 3)
        row.ratio[FULL] = round(res.makespan / optimum(alone), 4)
        row.violations[FULL], row.lost[FULL], row.duplicated[FULL] = 0, res.lost, res.duplicated
        rows.append(row)
        if progress is not None:
            progress(i + 1, count)
    return BatteryReport(rows=rows, summary=summary(rows, names + [FULL]))


def summary(rows: list[BatteryRow], names: Sequence[str]) -> dict[str, dict[str, float]]:
    out = {}
    for name in names:
        ratios = sorted(r.ratio[name] for r in rows)
        out[name] = {
            "median": statistics.median(ratios), "p90": ratios[int(0.9 * (len(ratios) - 1))], "worst": ratios[-1],
            "best": ratios[0], "within_3pct": sum(1 for x in ratios if x <= 1.03),
            "within_10pct": sum(1 for x in ratios if x <= 1.10),
            "violations": sum(r.violations[name] for r in rows), "lost": sum(r.lost[name] for r in rows),
            "duplicated": sum(r.duplicated[name] for r in rows),
        }
    return out


def format_report(rep: BatteryReport) -> str:
    n = len(rep.rows)
    lines = [f"{n} scenarios, {sum(r.programs for r in rep.rows)} programs; makespan / exact optimum "
             "(robots below their reserve host no teammates' programs)",
             f"{'variant':14s} {'median':>7s} {'p90':>7s} {'worst':>7s} {'best':>7s} {'<=3%':>6s} {'<=10%':>6s} "
             f"{'on low':>6s} {'lost':>5s} {'dup':>4s}"]
    for name, s in rep.summary.items():
        lines.append(f"{name:14s} {s['median']:7.3f} {s['p90']:7.3f} {s['worst']:7.3f} {s['best']:7.3f} "
                     f"{int(s['within_3pct']):6d} {int(s['within_10pct']):6d} {int(s['violations']):6d} "
                     f"{int(s['lost']):5d} {int(s['duplicated']):4d}")
    lines.append("on low = teammates' programs that ran on a robot below its reserve; a ratio below 1 beats the "
                 "model's optimum (moving programs, or using robots the model keeps out)")
    return "\n".join(lines)
