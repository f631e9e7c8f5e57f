"""How good a distribution is: the paper's classification and the optimum.

How this works: for identical programs on identical, unloaded robots the
paper (section 4.1.1) calls a distribution *optimal* when moving one program
cannot even out the counts (max - min <= 1) and *near optimal* when one move
makes it optimal. For loaded or heterogeneous teams we judge by the makespan
the same processor-sharing model predicts: identical programs that start
together on a robot with ``c`` cores, speed ``s`` and ``b`` background
processes all finish after ``work / (s * min(1, c / (k + b)))`` with ``k``
programs there. The best allocation under that model is found exactly by
giving programs one at a time to the robot whose finish time grows least
(optimal for minimising the maximum of non-decreasing per-robot costs).
"""

from __future__ import annotations

import heapq
from typing import Sequence

import msgspec

OPTIMAL = "optimal"
NEAR_OPTIMAL = "near_optimal"
NON_OPTIMAL = "non_optimal"


class Machine(msgspec.Struct, frozen=True, array_like=True):
    cores: int
    speed: float
    background: int = 0


def rate(m: Machine, k: int) -> float:
    """Work units per second each of ``k`` programs gets on ``m`` beside its
    busy processes (processor sharing)."""
    return m.speed * min(1.0, m.cores / (k + m.background))


def finish_time(m: Machine, k: int, work: float) -> float:
    """When k identical programs started together on m all finish."""
    if k <= 0:
        return 0.0
    return work / rate(m, k)


def model_makespan(counts: Sequence[int], team: Sequence[Machine], work: float) -> float:
    return max((finish_time(m, k, work) for m, k in zip(team, counts)), default=0.0)


def optimal_allocation(n: int, team: Sequence[Machine], work: float) -> tuple[list[int], float]:
    """The allocation of n identical programs with the smallest makespan."""
    counts = [0] * len(team)
    heap = [(finish_time(m, 1, work), i) for i, m in enumerate(team)]
    heapq.heapify(heap)
    worst = 0.0
    for _ in range(n):
        t, i = heapq.heappop(heap)
        counts[i] += 1
        worst = max(worst, t)
        heapq.heappush(heap, (finish_time(team[i], counts[i] + 1, work), i))
    return counts, worst


def classify_counts(counts: Sequence[int]) -> str:
    """The paper's classification for identical programs and robots."""
    if not counts or max(counts) - min(counts) <= 1:
        return OPTIMAL
    moved = list(counts)
    moved[moved.index(max(moved))] -= 1
    moved[moved.index(min(moved))] += 1
    return NEAR_OPTIMAL if max(moved) - min(moved) <= 1 else NON_OPTIMAL


def classify_model(counts: Sequence[int], team: Sequence[Machine], work: float) -> str:
    """Optimal if the model's makespan equals the best achievable; near
    optimal if moving one program gets there."""
    best = optimal_allocation(sum(counts), team, work)[1]
    tol = best * 1e-9
    if model_makespan(counts, team, work) <= best + tol:
        return OPTIMAL
    for i, ki in enumerate(counts):
        if ki == 0:
            continue
        for j in range(len(counts)):
            if j == i:
                continue
            moved = list(counts)
            moved[i] -= 1
            moved[j] += 1
            if model_makespan(moved, team, work) <= best + tol:
                return NEAR_OPTIMAL
    return NON_OPTIMAL


def classify(counts: Sequence[int], team: Sequence[Machine], work: float) -> str:
    """Counts rule for identical unloaded robots, model rule otherwise."""
    if len({(m.cores, m.speed) for m in team}) <= 1 and all(m.background == 0 for m in team):
        return classify_counts(counts)
    return classify_model(counts, team, work)


def free_core_violation(counts: Sequence[int], team: Sequence[Machine]) -> bool:
    """True if a program sits on a loaded robot while some unloaded robot
    still had a free core (fewer programs than cores)."""
    on_loaded = any(k > 0 for m, k in zip(team, counts) if m.background > 0)
    spare = any(k < m.cores for m, k in zip(team, counts) if m.background == 0)
    return on_loaded and spare
