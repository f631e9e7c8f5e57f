"""The exact optimum of a several-origins scenario, where a search can prove it.

How this works: the model is the sweep's (``ramps.experiments.sweep``):
identical programs of ``work`` units released at known times, each placed
on one robot when it is released and never moved, every robot sharing its
cores among its programs and its busy processes (processor sharing).
``exact_optimum`` searches every placement by branch and bound:

- programs are placed in release order; a robot's programs finish in the
  order they came (equal work, equal shares), so a robot's finish time is
  that of its last program (``finish``);
- a placement is cut as soon as its makespan, or a lower bound on what the
  programs still to place add, reaches the best schedule found so far. The
  bound gives each robot its programs so far plus ``x`` more, all released
  at the next release time, and chooses the ``x`` greedily, which is exact
  for the min-max of finish times that grow with ``x``. It rests on two
  properties of processor sharing that ``tests/test_optimum.py`` checks on
  thousands of random robots but that are not proven here: a robot never
  ends earlier with more programs, nor when its programs still to come are
  all released at the first of their times (releasing *one* program
  earlier can make a robot end later, so the bound moves them all);
- robots with the same capacity and the same programs are interchangeable:
  only one of them is tried;
- the search starts from a known feasible schedule (the oracle's), so it
  only has to find better ones or prove there are none.

A search that visits ``max_nodes`` placements without finishing proves
nothing: the result then says so (``proven`` False), and the optimum lies
between the sweep's lower bound and the best schedule found. Node counts,
not time, bound it, so a sweep gives the same answer on any machine.
"""

from __future__ import annotations

import heapq
from typing import Sequence

from ramps.experiments.metrics import Machine

_EPS = 1e-9


def finish(m: Machine, releases: Sequence[float], work: float) -> float:
    """When the last of programs released at ``releases`` (sorted) ends on ``m``."""
    t, last, i, n = 0.0, 0.0, 0, len(releases)
    left: list[float] = []
    while i < n or left:
        nxt = releases[i] if i < n else float("inf")
        if left:
            rate = m.speed * min(1.0, m.cores / (len(left) + m.background))
            first = min(left)
            if t + first / rate <= nxt:
                t += first / rate
                left = [x - first for x in left if x - first > _EPS]
                last = t
                continue
            done = (nxt - t) * rate
            left = [x - done for x in left]
        t = nxt
        left.append(work)
        i += 1
    return last


def exact_optimum(team: Sequence[Machine], releases: Sequence[float], work: float, upper: float,
                  max_nodes: int = 200_000) -> tuple[float, bool, int]:
    """(best makespan found, whether it is proven optimal, placements visited).

    ``upper`` is the makespan of a feasible schedule (the oracle's); the
    result is never above it."""
    rel = sorted(releases)
    n, robots = len(rel), range(len(team))
    placed: list[list[float]] = [[] for _ in robots]
    best = upper
    nodes = 0
    cache: dict[tuple, float] = {}

    def ends(i: int, extra: int, at: float) -> float:
        key = (team[i], tuple(placed[i]), extra, at)
        v = cache.get(key)
        if v is None:
            v = cache[key] = finish(team[i], placed[i] + [at] * extra, work)
        return v

    def bound(j: int) -> float:
        """No placement of programs j.. ends before this (see the module docstring)."""
        at = rel[j]
        extra = [0] * len(team)
        worst = max(ends(i, 0, at) for i in robots)
        heap = [(ends(i, 1, at), i) for i in robots]
        heapq.heapify(heap)
        for _ in range(n - j):
            t, i = heapq.heappop(heap)
            extra[i] += 1
            worst = max(worst, t)
            if worst >= best - _EPS:
                break
            heapq.heappush(heap, (ends(i, extra[i] + 1, at), i))
        return worst

    def search(j: int) -> bool:
        """False once the node budget is spent."""
        nonlocal best, nodes
        nodes += 1
        if nodes > max_nodes:
            return False
        if j == n:
            best = min(best, max(ends(i, 0, 0.0) for i in robots))
            return True
        if bound(j) >= best - _EPS:
            return True
        seen, options = set(), []
        for i in robots:
            key = (team[i], tuple(placed[i]))
            if key not in seen:
                seen.add(key)
                options.append((ends(i, 1, rel[j]), i))
        for t, i in sorted(options):
            if t >= best - _EPS:
                break
            placed[i].append(rel[j])
            ok = search(j + 1)
            placed[i].pop()
            if not ok:
                return False
        return True

    proven = search(0) if n else True
    return best, proven, nodes
