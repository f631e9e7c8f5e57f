"""The exact fewest-misses placement of a small deadline scenario.

How this works: the model is the simulator's without its control traffic.
Each program of ``ramps.experiments.deadlines``' family is released at its
submission time (``jobs_of``), placed on one robot then, never moved, and
shares that robot's cores with the programs placed there (processor
sharing: each of ``k`` programs computes at ``speed * min(1, cores / k)``).
A program placed off its origin starts computing when its parameters have
crossed (two latencies and the payload) and is delivered a latency and the
result after it ends, ``comm_time`` in all; one on its origin has neither.
It misses its deadline if it is delivered after it.

``optimum`` finds, over every such placement, the fewest misses and, among
the placements with that many, the shortest makespan (last delivery after
the first release). A robot's misses and last delivery depend only on which
programs it runs, so it prices every subset of programs on every robot by
simulating processor sharing (``subset_costs``) and combines robots by
dynamic programming over subsets: the fewest misses of a set of programs on
the first ``r`` robots is the fewest over its splits between those and
robot ``r``, and of equally few, the smallest makespan (misses add,
makespans take the larger, so the order is kept). That is exact for this
model, not a bound, and costs ``robots * 3**programs`` steps: it is for
small instances (``MAX_PROGRAMS``).

What it is not: a schedule that may move programs, or run them other than
by processor sharing (earliest deadline first on a core, say), can do
better; ``ramps.experiments.deadlines.miss_bound`` bounds every schedule.
"""

from __future__ import annotations

import statistics

import msgspec
import numpy as np

from ramps.core.cost import NetworkEstimate
from ramps.experiments.deadlines import VARIANTS, Job, generate, jobs_of, miss_bound, simulate_variants
from ramps.sim.scenario import Scenario

#: the largest instance ``optimum`` takes (3**12 splits per robot)
MAX_PROGRAMS = 12
_EPS = 1e-9


class Optimum(msgspec.Struct, frozen=True, kw_only=True):
    #: the fewest programs that miss their deadline, and the shortest
    #: makespan of a placement with that many misses
    misses: int
    makespan: float
    #: that placement: each job's robot (``jobs_of``' order)
    hosts: list[str]


def shared_ends(starts: list[float], works: list[float], speed: float, cores: int) -> list[float]:
    """When each program ends on one robot, started at ``starts`` with
    ``works`` units, under processor sharing."""
    n = len(starts)
    ends = [0.0] * n
    order = sorted(range(n), key=starts.__getitem__)
    left: dict[int, float] = {}
    t, i = 0.0, 0
    while i < n or left:
        nxt = starts[order[i]] if i < n else float("inf")
        if not left:
            t = nxt
            left[order[i]] = works[order[i]]
            i += 1
            continue
        rate = speed * min(1.0, cores / len(left))
        first = min(left, key=left.__getitem__)
        if t + left[first] / rate <= nxt + _EPS:
            dt = left[first] / rate
            t += dt
            for j in list(left):
                left[j] -= dt * rate
                if left[j] <= _EPS:
                    ends[j] = t
                    del left[j]
        else:
            for j in left:
                left[j] -= (nxt - t) * rate
            t = nxt
            left[order[i]] = works[order[i]]
            i += 1
    return ends


def subset_costs(jobs: list[Job], robot: str, speed: float, cores: int,
                 net: NetworkEstimate) -> tuple[np.ndarray, np.ndarray]:
    """For every subset of ``jobs`` (a bit mask), its misses and its last
    delivery on ``robot``."""
    n = len(jobs)
    misses = np.zeros(1 << n, dtype=np.int64)
    last = np.zeros(1 << n, dtype=np.float64)
    comm_in = [0.0 if j.origin == robot else 2 * net.latency + j.payload / net.bandwidth for j in jobs]
    comm_out = [0.0 if j.origin == robot else net.latency + j.result / net.bandwidth for j in jobs]
    for mask in range(1, 1 << n):
        idx = [k for k in range(n) if mask >> k & 1]
        ends = shared_ends([jobs[k].release + comm_in[k] for k in idx], [jobs[k].work for k in idx], speed, cores)
        done = [e + comm_out[k] for e, k in zip(ends, idx)]
        misses[mask] = sum(1 for d, k in zip(done, idx) if d > jobs[k].deadline + _EPS)
        last[mask] = max(done)
    return misses, last


def optimum(sc: Scenario) -> Optimum:
    """The fewest misses of any placement of ``sc`` in this module's model,
    then the shortest makespan among those (see the module's docstring)."""
    jobs = jobs_of(sc)
    n = len(jobs)
    if n > MAX_PROGRAMS:
        raise ValueError(f"{n} programs: the exact search takes at most {MAX_PROGRAMS}")
    net = NetworkEstimate(latency=sc.network.latency, bandwidth=sc.network.bandwidth)
    full = (1 << n) - 1
    masks = np.arange(1 << n, dtype=np.int64)
    # best[mask]: the fewest misses and then the smallest last delivery of
    # ``mask``'s programs on the robots so far; choice[r][mask]: robot r's part
    best_m = np.where(masks == 0, 0, 1 << 30).astype(np.int64)
    best_f = np.zeros(1 << n, dtype=np.float64)
    choice: list[np.ndarray] = []
    for robot in sc.team():
        cm, cf = subset_costs(jobs, robot.name, robot.speed, robot.cores, net)
        new_m, new_f = best_m.copy(), best_f.copy()  # robot r runs nothing
        part = np.zeros(1 << n, dtype=np.int64)
        for sub in range(1, 1 << n):
            sel = masks[(masks & sub) == sub]
            rest = sel ^ sub
            m = best_m[rest] + cm[sub]
            f = np.maximum(best_f[rest], cf[sub])
            better = (m < new_m[sel]) | ((m == new_m[sel]) & (f < new_f[sel] - _EPS))
            if better.any():
                won = sel[better]
                new_m[won], new_f[won], part[won] = m[better], f[better], sub
        best_m, best_f = new_m, new_f
        choice.append(part)
    hosts = [""] * n
    mask = full
    for robot, part in zip(reversed(sc.team()), reversed(choice)):
        sub = int(part[mask])
        for k in range(n):
            if sub >> k & 1:
                hosts[k] = robot.name
        mask ^= sub
    first = min((j.release for j in jobs), default=0.0)
    return Optimum(misses=int(best_m[full]), makespan=float(best_f[full]) - first if n else 0.0, hosts=hosts)


def small_scenarios(count: int, *, seed: int = 0, max_robots: int = 5) -> list[Scenario]:
    """The first ``count`` scenarios of the deadline family (same indices and
    seed as ``run_family``) small enough for ``optimum``: at most
    ``MAX_PROGRAMS`` programs on at most ``max_robots`` robots."""
    out: list[Scenario] = []
    i = 0
    while len(out) < count:
        sc = generate(i, seed)
        if len(jobs_of(sc)) <= MAX_PROGRAMS and len(sc.robots) <= max_robots:
            out.append(sc)
        i += 1
    return out


class SmallRow(msgspec.Struct, kw_only=True):
    scenario: str
    programs: int
    #: misses per variant (``VARIANTS``' names), of the optimum and of the bound
    misses: dict[str, int]
    makespan: dict[str, float]


def compare(count: int, *, seed: int = 0, sim_seed: int = 1) -> list[SmallRow]:
    """``small_scenarios(count, seed=seed)`` simulated with every variant of
    ``run_family`` on the same seed, with their ``optimum`` and ``miss_bound``."""
    rows = []
    for sc in small_scenarios(count, seed=seed):
        misses, makespan = simulate_variants(sc, VARIANTS, sim_seed)
        best = optimum(sc)
        misses["optimum"], makespan["optimum"] = best.misses, best.makespan
        misses["bound"] = miss_bound(sc)[0]
        rows.append(SmallRow(scenario=sc.name, programs=len(jobs_of(sc)), misses=misses, makespan=makespan))
    return rows


def summary(rows: list[SmallRow], reference: str = "optimum") -> dict[str, dict[str, float]]:
    """Per variant: its miss ratio over all rows, and the median and worst
    per scenario of its misses beyond ``reference``'s, as a fraction of the
    scenario's programs."""
    out = {}
    total = sum(r.programs for r in rows) or 1
    for name in rows[0].misses if rows else ():
        excess = sorted((r.misses[name] - r.misses[reference]) / r.programs for r in rows)
        out[name] = {"miss_ratio": sum(r.misses[name] for r in rows) / total,
                     "median_excess": statistics.median(excess), "worst_excess": excess[-1]}
    return out
