"""The cost model of the paper's eq. (1): move when T_here > T_there + T_comm.

How this works: a program's computation time on a robot is its work divided
by the speed one program gets there under processor sharing. With
``programs`` ramps programs (the new one included) next to ``background``
other runnable tasks on ``cores`` cores, each task gets at most one core and
the cores are shared in proportion to the tasks' scheduler weights: Linux's
CFS gives a process of niceness n the weight 1024 / 1.25**n (the kernel's
table), so ramps workers at nice 10 weigh ``weight`` = 110/1024 of the
robot's own software at nice 0. With ``weight`` = 1 (the paper's model) this
is ``speed * min(1, cores / (runnable + 1))``, where ``runnable`` counts the
tasks already competing (background and ramps programs) and ``+ 1`` is the
program itself. Communication time is the request, the acceptance and the
result crossing the link: three latencies plus the bytes of parameters and
result over the bandwidth. Pure functions; the only state is a memo of
processor shares by count (``_shares``), which changes no result.
"""

from __future__ import annotations

from functools import reduce
from itertools import repeat
from operator import add, mul, sub, truediv

import msgspec

#: the kernel's sched_prio_to_weight for nice -20..19 (kernel/sched/core.c)
_CFS_WEIGHTS = (
    88761, 71755, 56483, 46273, 36291, 29154, 23254, 18705, 14949, 11916,
    9548, 7620, 6100, 4904, 3906, 3121, 2501, 1991, 1586, 1277,
    1024, 820, 655, 526, 423, 335, 272, 215, 172, 137,
    110, 87, 70, 56, 45, 36, 29, 23, 18, 15,
)


class NetworkEstimate(msgspec.Struct, frozen=True, kw_only=True):
    """What an origin believes about its links (from profiling, paper 3.2)."""

    latency: float = 0.005
    bandwidth: float = 2.5e6


def nice_weight(nice: int) -> float:
    """CFS weight of a process at ``nice`` relative to one at nice 0 (10 -> 0.107)."""
    if not -20 <= nice <= 19:
        raise ValueError(f"nice must be -20..19, got {nice}")
    return _CFS_WEIGHTS[nice + 20] / 1024.0


#: the most of a robot's cores its node's own CPU (``LoadReport.node_cpu``) may take off
NODE_CPU_MAX = 0.5


def program_cores(cores: float, node_cpu: float) -> float:
    """The cores a full robot's programs can have: its cores less what its node
    itself uses, at most ``NODE_CPU_MAX`` of them (the cost model's, the
    simulator's and the testbed's fidelity model's one rule)."""
    return cores - min(node_cpu, NODE_CPU_MAX * cores)


def program_share(cores: float, programs: float, background: float = 0.0, weight: float = 1.0) -> float:
    """Fraction of one core each of ``programs`` ramps programs gets next to
    ``background`` other runnable tasks, the programs weighing ``weight`` each
    against a background task's 1: weighted processor sharing with at most
    one core per task, so the heavier class reaches a whole core first and the
    lighter one shares what is left."""
    if programs <= 0 or programs + background <= cores:
        return 1.0
    per_weight = cores / (background + weight * programs)
    if max(weight, 1.0 if background > 0 else 0.0) * per_weight <= 1.0:
        return weight * per_weight  # nobody has a whole core
    if weight < 1.0:  # every background task has a core; the programs share the rest
        return (cores - background) / programs
    return 1.0  # the programs are the heavier class: each has a core


def weighted_shares(cores: float, weights: list[float]) -> tuple[list[float], float]:
    """Cores each task gets when tasks of these scheduler weights share
    ``cores`` (at most one core each, the heaviest reach a whole core first),
    and the cores per unit of weight of the tasks below a core (``inf`` when
    every task has a whole one). ``program_share`` is its two-class case."""
    order = sorted(range(len(weights)), key=lambda i: -weights[i])
    out = [1.0] * len(weights)
    left, weight_left = float(cores), float(sum(weights))
    for n, i in enumerate(order):
        if len(order) - n <= left:  # a core each for the rest
            return out, float("inf")
        if weights[i] * left / weight_left <= 1.0:  # nobody left reaches a core
            level = left / weight_left
            for j in order[n:]:
                out[j] = weights[j] * level
            return out, level
        left -= 1.0
        weight_left -= weights[i]
    return out, float("inf")


def share(cores: int, runnable: float) -> float:
    """Fraction of one core a newly started task gets (all tasks weigh the same)."""
    return min(1.0, cores / (runnable + 1.0))


def compute_time(work: float, cores: int, speed: float, runnable: float) -> float:
    """Seconds for ``work`` units on a robot with ``runnable`` competing tasks."""
    return work / (speed * share(cores, runnable))


def comm_time(payload: int, result: int, net: NetworkEstimate) -> float:
    """Seconds to offload parameters and bring the result back."""
    return 3.0 * net.latency + (payload + result) / net.bandwidth


def shared_finish_time(work: float, others: list[float], cores: float, speed: float, background: float = 0.0,
                       weight: float = 1.0) -> float:
    """Seconds until a new program of ``work`` units finishes on a robot
    whose ramps programs have ``others`` units left each, under processor
    sharing: every program runs at the same rate, which rises each time one
    of them ends (``program_share``). With no others this is
    ``work / (speed * program_share(cores, 1, background, weight))``; with
    others of the new program's own size, the count-based estimate.

    Runs once per program on every busy host an origin considers, for every
    placement: the sum of each program's stretch is taken by C loops
    (``map``, ``reduce``) over the shares of ``_shares``, term by term in
    the order and with the operations of the plain loop, so the float is
    the same to the last bit (``tests/test_dispatch_path.py``)."""
    left = [x for x in others if x < work]
    k = len(others) + 1
    m = len(left)
    if not m:
        return work / (speed * program_share(cores, k, background, weight))
    left.sort()
    shares = _shares(cores, background, weight, k)[k:k - m:-1]  # the shares at k, k - 1, ... k - m + 1 programs
    before = [0.0]
    before += left
    # t += (x - done) / (speed * share) for each x, from t = 0.0
    t = reduce(add, map(truediv, map(sub, left, before), map(mul, repeat(speed, m), shares)), 0.0)
    return t + (work - left[-1]) / (speed * program_share(cores, k - m, background, weight))


def pool_finish_time(work: float, others: list[float], cores: float, speed: float, background: float = 0.0,
                     weight: float = 1.0) -> float:
    """Seconds until the last of a new program of ``work`` units and ramps
    programs with ``others`` units left each ends, all sharing one robot's
    cores (or slots) under processor sharing: ``shared_finish_time`` of the
    largest of them (``RampsConfig.place_by`` "pool_end")."""
    top = max(others, default=work)
    if top <= work:
        return shared_finish_time(work, others, cores, speed, background, weight)
    rest = list(others)
    rest.remove(top)
    rest.append(work)
    return shared_finish_time(top, rest, cores, speed, background, weight)


#: the share of each program at each count, per (cores, background, weight) (``_shares``)
_SHARE_TABLES: dict[tuple[float, float, float], list[float]] = {}


def _shares(cores: float, background: float, weight: float, k: int) -> list[float]:
    """The share of one core each program gets with ``j`` of them, for every
    ``j`` up to at least ``k`` (index ``j``; 0 unused): ``program_share``
    with the same operations. Kept per robot shape (at most 64 shapes)."""
    key = (cores, background, weight)
    table = _SHARE_TABLES.get(key)
    if table is not None and len(table) > k:
        return table
    top = max(weight, 1.0 if background > 0 else 0.0)
    table = [1.0]
    for j in range(1, max(k + 1, 64, 2 * len(_SHARE_TABLES.get(key, ())))):
        if j + background <= cores:
            share = 1.0
        else:
            per_weight = cores / (background + weight * j)
            if top * per_weight <= 1.0:
                share = weight * per_weight
            elif weight < 1.0:
                share = (cores - background) / j
            else:
                share = 1.0
        table.append(share)
    if len(_SHARE_TABLES) >= 64:
        _SHARE_TABLES.clear()
    _SHARE_TABLES[key] = table
    return table
