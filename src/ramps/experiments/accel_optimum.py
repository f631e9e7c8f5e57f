"""The exact shortest makespan of a small accelerator scenario, by CP-SAT.

How this works: the model is the simulator's without its control traffic.
Every program of the scenario is released at once (a batch: the family of
``ramps.experiments.accelerators`` submits each at the same instant) and is
placed on one *pool*, never moved: a robot's CPU cores, or the slots of one
kind of accelerator it has. Where it goes is what the product does: a
program that can use an accelerator runs on its slots on a robot that has
that kind, and on the CPUs (with its CPU work) of one that has not, where
``cpu_fallback`` allows it (``choose_device`` lets it also choose a CPU on a
robot with the accelerator: a relaxation of what ramps may do). A program
``j`` on pool ``p`` computes ``q[j, p] = work / speed`` alone (its CPU work
at the robot's core speed, or its accelerator work at the slot speed); the
``k`` programs of a pool of ``c`` cores or slots share them by processor
sharing, at most one each.

Processor sharing of a batch: with the pool's times ``q_1 <= ... <= q_k``
and ``k > c``, each gets ``c / n`` of a core while ``n > c`` remain, so the
pool ends at ``q_k + (q_1 + ... + q_(k-c)) / c`` (summing the phases by
parts), and at ``q_k`` when ``k <= c``. That is the packing bound
``max(q_k, sum(q) / c)`` (McNaughton's preemptive optimum) only when ``k <=
c`` or the pool's ``c`` longest programs are equally long (identical
programs, as ``ramps.experiments.optimum`` has them); otherwise it is
larger (two cores, times 1, 1 and 10: 10.5, not 10), and this module
optimises the processor-sharing makespan, not the bound. CP-SAT encodes it
exactly and linearly: choose at most ``c`` programs ``y`` of the pool; for
every program ``j`` there, ``c * q_j + sum(q_i for i in the pool, not in y)
<= c * T`` (the best ``y`` is the ``c`` longest, which the solver is free to
choose, so the constraints hold exactly when the pool ends by ``T``).

Communication: a pool that runs programs of other origins ends
``comm_time`` later (``ramps.core.cost``: three latencies and the bytes of
parameters and result, the largest of its programs from elsewhere), as if
its programs started when their parameters had crossed and their results
crossed after the last one ended; its origin's own programs cost none.

Failures: a robot that crashes or is cut off ``at`` seconds after the
release may take only programs that end (and whose results cross) by
then: what it does after is lost. A placement that knew of the failure
beforehand reaches the optimum; one that moves programs cannot do better
(a move restarts the program, and a program started there that does not
end in time only slows the others).

Times are whole milliseconds inside the solver; ``makespan`` is the exact
processor-sharing makespan of the placement it found (``pool_makespan``),
``bound`` the solver's proven lower bound less the rounding. ``proven``
says whether CP-SAT proved optimality within its time limit: where it did
not, compare with ``bound`` (no placement ends before it) and say so.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import msgspec

from ramps.core.accelerators import parse_accelerator
from ramps.core.cost import NetworkEstimate, comm_time
from ramps.sim.scenario import Scenario

#: solver units per second (CP-SAT wants integers)
SCALE = 1000


class Job(msgspec.Struct, frozen=True, kw_only=True):
    """One program of a scenario as the reference sees it."""

    origin: str
    #: its true work on a CPU, and on an accelerator of ``accelerator`` ("" = none)
    work: float
    accelerator: str = ""
    accelerator_work: float = 0.0
    cpu_fallback: bool = True
    payload: int = 1000
    result: int = 1000


class Pool(msgspec.Struct, frozen=True, kw_only=True):
    """A robot's CPU cores (``kind`` "") or one kind of its accelerators."""

    robot: str
    kind: str
    slots: int
    speed: float
    #: seconds after the release by which everything on it must be delivered
    #: (the robot fails then); None: no limit
    until: float | None = None


class AccelOptimum(msgspec.Struct, frozen=True, kw_only=True):
    #: the processor-sharing makespan of the best placement found, seconds
    makespan: float
    #: no placement in the model ends before this
    bound: float
    #: CP-SAT proved the placement optimal (makespan is the optimum)
    proven: bool
    #: each job's pool as "robot" or "robot:kind" (``jobs_of``' order)
    hosts: list[str]
    seconds: float = 0.0


def jobs_of(sc: Scenario) -> list[Job]:
    """Every program of ``sc`` with its true costs."""
    return [Job(origin=p.origin, work=p.work, accelerator=p.accelerator,
                accelerator_work=p.accelerator_work or p.work if p.accelerator else 0.0,
                cpu_fallback=p.cpu_fallback, payload=p.payload, result=p.result)
            for p in sc.programs for _ in range(p.count)]


def pools_of(sc: Scenario) -> list[Pool]:
    """Every robot's CPU pool and accelerator pools; a robot that crashes or
    is cut off (``sc.faults``, first of them) gets its time limit."""
    fails: dict[str, float] = {}
    for f in sorted(sc.faults, key=lambda f: f.at):
        if f.kind in ("crash", "network", "freeze"):
            fails.setdefault(f.robot, f.at)
    out = []
    for r in sc.team():
        until = fails.get(r.name)
        out.append(Pool(robot=r.name, kind="", slots=r.cores, speed=r.speed, until=until))
        for a in (parse_accelerator(t) for t in r.accelerators):
            out.append(Pool(robot=r.name, kind=a.kind, slots=a.count, speed=a.speed, until=until))
    return out


def allowed(job: Job, pool: Pool, kinds: frozenset[str], *, choose_device: bool = False) -> bool:
    """Whether ``job`` may run on ``pool`` (``kinds``: its robot's accelerator kinds)."""
    if pool.kind:
        return pool.kind == job.accelerator
    if job.accelerator and not job.cpu_fallback:
        return False
    return choose_device or job.accelerator not in kinds


def alone(job: Job, pool: Pool) -> float:
    """Seconds ``job`` computes alone on ``pool``."""
    return (job.accelerator_work if pool.kind else job.work) / pool.speed


def shared_batch_end(times: Sequence[float], slots: int) -> float:
    """When the last of programs started together, computing ``times``
    seconds alone, ends on ``slots`` cores shared by processor sharing."""
    if not times:
        return 0.0
    q = sorted(times)
    k = len(q)
    return q[-1] + (sum(q[:k - slots]) / slots if k > slots else 0.0)


def pool_makespan(jobs: Sequence[Job], pool: Pool, on: Sequence[int], net: NetworkEstimate) -> float:
    """The last delivery of jobs ``on`` (indices) on ``pool`` in this model."""
    if not on:
        return 0.0
    comm = max((comm_time(jobs[j].payload, jobs[j].result, net) for j in on if jobs[j].origin != pool.robot),
               default=0.0)
    return shared_batch_end([alone(jobs[j], pool) for j in on], pool.slots) + comm


def makespan_of(sc: Scenario, hosts: Sequence[str]) -> float:
    """The model's makespan of placing job i on pool ``hosts[i]`` ("robot" or "robot:kind")."""
    jobs, pools = jobs_of(sc), pools_of(sc)
    net = NetworkEstimate(latency=sc.network.latency, bandwidth=sc.network.bandwidth)
    named = {_name(p): p for p in pools}
    return max((pool_makespan(jobs, p, [j for j, h in enumerate(hosts) if h == name], net)
                for name, p in named.items()), default=0.0)


def _name(p: Pool) -> str:
    return f"{p.robot}:{p.kind}" if p.kind else p.robot


def optimum(sc: Scenario, *, time_limit: float = 5.0, choose_device: bool = False) -> AccelOptimum:
    """The shortest makespan of any placement of ``sc``'s programs in this
    module's model (see its docstring), or the best found and a bound.

    Programs alike (the same origin and costs) are one group: the solver
    chooses how many of each group go to each pool, which leaves it no
    symmetric placements to search."""
    from ortools.sat.python import cp_model

    jobs, pools = jobs_of(sc), pools_of(sc)
    net = NetworkEstimate(latency=sc.network.latency, bandwidth=sc.network.bandwidth)
    kinds = {r: frozenset(p.kind for p in pools if p.robot == r and p.kind) for r in {p.robot for p in pools}}
    groups: dict[Job, list[int]] = {}
    for j, job in enumerate(jobs):
        groups.setdefault(job, []).append(j)
    kinds_of = list(groups)
    model = cp_model.CpModel()
    n: dict[tuple[int, int], cp_model.IntVar] = {}  # programs of group g on pool p
    on: dict[tuple[int, int], cp_model.IntVar] = {}  # pool p runs some of group g
    top: dict[tuple[int, int], cp_model.IntVar] = {}  # of them, among the pool's ``slots`` longest
    q: dict[tuple[int, int], int] = {}
    for g, job in enumerate(kinds_of):
        size = len(groups[job])
        for p, pool in enumerate(pools):
            if allowed(job, pool, kinds[pool.robot], choose_device=choose_device):
                q[g, p] = max(1, round(alone(job, pool) * SCALE))
                n[g, p] = model.new_int_var(0, size, f"n{g}_{p}")
                on[g, p] = model.new_bool_var(f"b{g}_{p}")
                model.add(n[g, p] <= size * on[g, p])
                model.add(n[g, p] >= on[g, p])
                top[g, p] = model.new_int_var(0, min(size, pool.slots), f"t{g}_{p}")
                model.add(top[g, p] <= n[g, p])
        if not any((g, p) in n for p in range(len(pools))):
            raise ValueError(f"{sc.name}: its {job.accelerator or 'cpu'} programs of {job.origin} have nowhere to run")
        model.add(sum(n[g, p] for p in range(len(pools)) if (g, p) in n) == size)
    comm = [round(comm_time(job.payload, job.result, net) * SCALE) for job in kinds_of]
    horizon = sum(len(groups[job]) * max(v for (g2, _), v in q.items() if g2 == g) + comm[g]
                  for g, job in enumerate(kinds_of))
    makespan = model.new_int_var(0, horizon, "T")
    for p, pool in enumerate(pools):
        here = [g for g in range(len(kinds_of)) if (g, p) in n]
        if not here:
            continue
        c = pool.slots
        model.add(sum(top[g, p] for g in here) <= c)
        far = [g for g in here if kinds_of[g].origin != pool.robot]
        crossing = model.new_int_var(0, max((comm[g] for g in far), default=0), f"c{p}")
        for g in far:
            model.add(crossing >= comm[g] * on[g, p])
        work = sum(q[g, p] * n[g, p] for g in here)
        rest = work - sum(q[g, p] * top[g, p] for g in here)
        model.add(work + c * crossing <= c * makespan)  # implied; a stronger relaxation
        ends = [c * makespan] + ([c * round(pool.until * SCALE)] if pool.until is not None else [])
        for g in here:
            for end in ends:  # the robot fails at ``until``: it ends by then
                model.add(c * q[g, p] * on[g, p] + rest + c * crossing <= end)
            model.add((q[g, p] + (comm[g] if g in far else 0)) * on[g, p] <= makespan)  # implied too
    model.minimize(makespan)
    solver = cp_model.CpSolver()
    solver.parameters.max_deterministic_time = time_limit  # the same answer on any machine
    solver.parameters.max_time_in_seconds = 10 * time_limit + 10.0
    solver.parameters.num_workers = 1
    solver.parameters.random_seed = 0
    status = solver.solve(model)
    if status not in (cp_model.OPTIMAL, cp_model.FEASIBLE):
        raise ValueError(f"{sc.name}: CP-SAT found no placement in {time_limit} s ({solver.status_name(status)})")
    hosts = [""] * len(jobs)
    for g, job in enumerate(kinds_of):
        left = list(groups[job])
        for p in range(len(pools)):
            for _ in range(solver.value(n[g, p]) if (g, p) in n else 0):
                hosts[left.pop()] = _name(pools[p])
    exact = makespan_of(sc, hosts)
    rounding = (len(jobs) + 2) / SCALE  # each time and the communication rounded by half a unit at most
    bound = max(0.0, solver.best_objective_bound / SCALE - rounding)
    return AccelOptimum(makespan=exact, bound=min(bound, exact), proven=status == cp_model.OPTIMAL, hosts=hosts,
                        seconds=solver.wall_time)


def greedy(sc: Scenario, *, choose_device: bool = False, declared: bool = False) -> tuple[float, list[str]]:
    """ramps' rule with a perfect, instant view of the team: each program in
    submission order to the pool where it would end first (processor sharing
    with the programs placed before it, all started at once, plus its
    communication), with its true work, a robot that fails left out; (the
    model's makespan of that placement, the pools). ``declared``: the rule
    chooses by the accelerator work the programs declare
    (``accelerator_estimate``), as an origin that knows only that does; the
    makespan is still the true work's."""
    jobs, pools = jobs_of(sc), [p for p in pools_of(sc) if p.until is None]
    if declared:
        jobs = _declared_jobs(sc)
    net = NetworkEstimate(latency=sc.network.latency, bandwidth=sc.network.bandwidth)
    kinds = {r: frozenset(p.kind for p in pools if p.robot == r and p.kind) for r in {p.robot for p in pools}}
    on: list[list[float]] = [[] for _ in pools]
    hosts = []
    for job in jobs:
        best, pick = math.inf, 0
        for p, pool in enumerate(pools):
            if not allowed(job, pool, kinds[pool.robot], choose_device=choose_device):
                continue
            mine = alone(job, pool)
            t = _end_of_new(mine, on[p], pool.slots)
            if job.origin != pool.robot:
                t += comm_time(job.payload, job.result, net)
            if t < best - 1e-9:
                best, pick = t, p
        on[pick].append(alone(job, pools[pick]))
        hosts.append(_name(pools[pick]))
    return makespan_of(sc, hosts), hosts


def _declared_jobs(sc: Scenario) -> list[Job]:
    """``jobs_of(sc)`` with each program's declared accelerator work."""
    return [Job(origin=p.origin, work=p.work, accelerator=p.accelerator,
                accelerator_work=(p.accelerator_estimate or p.accelerator_work or p.work) if p.accelerator else 0.0,
                cpu_fallback=p.cpu_fallback, payload=p.payload, result=p.result)
            for p in sc.programs for _ in range(p.count)]


def _end_of_new(mine: float, others: Sequence[float], slots: int) -> float:
    """When a program of ``mine`` seconds alone ends beside ``others``, all
    started together, under processor sharing of ``slots``."""
    t = done = 0.0
    k = len(others) + 1
    for x in sorted(o for o in others if o < mine):
        t += (x - done) * max(1.0, k / slots)
        done = x
        k -= 1
    return t + (mine - done) * max(1.0, k / slots)
