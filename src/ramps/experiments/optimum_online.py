"""How far above the optimum every online placement must be (``online_limit``, ``online_bound``).

How this works: a placement that decides each program at its release,
knowing the past but not the future, places the first k programs the same
way whether more come later or not, so it meets every *prefix* of the
scenario (the programs released up to some time) with the same first
decisions. ``online_limit`` searches every such placement (small scenarios
only) for the least worst ratio to the prefixes' optima (``solve``).
``online_bound`` shows a lower bound on that ratio without searching
placements: schedules of the prefixes (``improve``, ``anneal``) say which
robots a placement within ``rho`` may use for each program, and the
two-window bound (``ramps.experiments.optimum_bounds.window_bound``'s test,
with ``allowed``) says whether any schedule so kept ends by ``rho`` times
the whole scenario's; ``rho`` is bisected.
"""

from __future__ import annotations

import math
import time as _wallclock
from typing import Sequence

import msgspec

from ramps.experiments.metrics import Machine, rate
from ramps.experiments.optimum import anneal, finish, improve, makespan_of, solve
from ramps.experiments.optimum_bounds import Allowed, unreachable, wave_starts, window_pairs

_EPS = 1e-9


class OnlineLimit(msgspec.Struct, kw_only=True, frozen=True):
    """What no placement that decides each program when it is released can beat."""

    #: the least, over every way of placing the programs in release order, of the worst
    #: ratio to the optimum over the scenario's prefixes (below)
    ratio: float
    #: the placement that reaches it (program k in release order on robot ``assignment[k]``)
    assignment: list[int]
    #: the optimum of each prefix: the programs released up to each distinct release time
    prefix_optima: list[float]
    nodes: int


def online_limit(team: Sequence[Machine], releases: Sequence[float], work: float,
                 max_nodes: int = 1_000_000) -> OnlineLimit | None:
    """The best ratio to the optimum that any online placement can guarantee on this
    scenario and its prefixes, or None where the search is too big (``max_nodes``).

    A placement that decides each program at its release, knowing the past but not the
    future, places the first k programs the same way whether more come later or not. So
    it meets every *prefix* of the scenario (the programs released up to some time, the
    rest never) with the same first decisions, and on one of them it is at least
    ``ratio`` above that prefix's optimum: the minimum, over all placements, of their
    worst prefix ratio. A scenario where it exceeds 1.05 is one where no online
    placement, however informed about the present, is within 5% of the (clairvoyant)
    optimum on each of the scenario and its prefixes. Exhaustive over placements
    (with cuts), so for small scenarios only."""
    rel = sorted(releases)
    n = len(rel)
    if n == 0:
        return OnlineLimit(ratio=1.0, assignment=[], prefix_optima=[], nodes=0)
    # the prefixes end where a release time is followed by a later one (programs released
    # at the same moment are decided knowing of each other)
    cuts = [k for k in range(1, n + 1) if k == n or rel[k] > rel[k - 1] + _EPS]
    optima = []
    for k in cuts:
        found = solve(team, rel[:k], work, [0] * k, time_limit=math.inf, max_nodes=max_nodes)
        if not found.proven:
            return None
        optima.append(found.best)
    opt_at = {k: o for k, o in zip(cuts, optima)}
    best_ratio, best_assignment = math.inf, list[int]()
    nodes = 0
    placed: list[int] = []

    def dfs(worst: float) -> bool:
        nonlocal nodes, best_ratio, best_assignment
        k = len(placed)
        if k in opt_at:
            worst = max(worst, makespan_of(team, rel[:k], work, placed) / opt_at[k])
        if worst >= best_ratio - _EPS:
            return True
        if k == n:
            best_ratio, best_assignment = worst, list(placed)
            return True
        seen = set()
        for i, m in enumerate(team):
            key = (m, tuple(j for j, a in enumerate(placed) if a == i))
            if key in seen:  # the same robot with the same programs: tried once
                continue
            seen.add(key)
            nodes += 1
            if nodes > max_nodes:
                return False
            placed.append(i)
            ok = dfs(worst)
            placed.pop()
            if not ok:
                return False
        return True

    if not dfs(1.0):
        return None
    return OnlineLimit(ratio=best_ratio, assignment=best_assignment, prefix_optima=optima, nodes=nodes)


class OnlineBound(msgspec.Struct, kw_only=True, frozen=True):
    """A lower bound on what any online placement can guarantee, for teams too big for
    ``online_limit`` (``online_bound``)."""

    #: no placement deciding each program at its release is within this ratio of the
    #: optimum on every one of the scenario and its prefixes (1.0: nothing shown)
    ratio: float
    #: an upper bound on the scenario's optimum (the best schedule found)
    optimum_at_most: float
    #: robots such a placement (within ``ratio``) may not use at all
    unusable: list[int]
    #: an upper bound on the optimum of each wave's prefix (programs up to its end)
    prefix_optima: list[float]
    seconds: float


def online_bound(team: Sequence[Machine], releases: Sequence[float], work: float,
                 assignment: Sequence[int] | None = None, *, upper: float | None = None, steps: int = 100_000,
                 time_limit: float = 60.0, tolerance: float = 1e-4) -> OnlineBound:
    """How far above the optimum every online placement must be, on the scenario or
    one of its prefixes, shown without searching placements (``online_limit`` does,
    and cannot beyond a few programs).

    The argument. A placement that decides program j at its release cannot tell the
    scenario from its prefix P(j) (the programs released up to r_j; its wave's end is
    used, whose optimum is no smaller). On P(j), program j placed on robot i ends no
    earlier than ``r_j + work / rate(m_i, 1)``; so a placement within ``rho`` of every
    optimum puts j on i only if that is at most ``rho * OPT(P(j))``, and ``OPT(P(j))``
    is at most the schedule ``anneal`` finds for P(j). The two-window bound then runs
    with each kind of program (released in a window, or after it) kept off the robots
    none of them may use (``window_bound``'s ``allowed``). Where no schedule so kept
    ends by ``rho`` times a schedule of the whole scenario, no online placement is
    within ``rho`` of the optimum on the scenario and all its prefixes; ``ratio`` is
    the largest such ``rho``, by bisection (1.0 when none is shown). It rests on the
    same properties of processor sharing as the bounds above.

    Where it shows most: the clairvoyant optimum parks the first programs on slow
    robots, to end when the last wave does and leave the fast robots to the later
    programs; on its prefix, a placement doing that is several times the optimum."""
    started = _wallclock.perf_counter()
    deadline = started + time_limit
    rel = sorted(releases)
    n = len(rel)
    if n == 0 or not team:
        return OnlineBound(ratio=1.0, optimum_at_most=0.0, unusable=[], prefix_optima=[], seconds=0.0)
    starts = wave_starts(rel)
    wave_end = [max(k for k in range(n) if rel[k] < min((s for s in starts if s > rel[j]), default=math.inf))
                for j in range(n)]

    # a third of the time for the prefixes' schedules, a third for the whole one's, a third to bisect
    waves_ends = sorted(set(wave_end))
    ub: dict[int, float] = {}
    for e in waves_ends:
        share = time_limit / 3 / len(waves_ends)
        ub[e] = _short_schedule(team, rel[:e + 1], work, None, steps, min(deadline, _wallclock.perf_counter() + share))
    full = ub[n - 1]
    if assignment is not None:
        full = min(full, _short_schedule(team, rel, work, assignment, steps, min(deadline, _wallclock.perf_counter() + time_limit / 3)))
    if upper is not None:
        full = min(full, upper)
    ub[n - 1] = full
    # program j may go to robot i within rho from rho = beta[i][j] on
    beta = [[(rel[j] + work / rate(m, 1)) / ub[wave_end[j]] for j in range(n)] for m in team]
    index = {r: k for k, r in reversed(list(enumerate(rel)))}  # a release time -> its first program

    pairs = window_pairs(rel, single=True)

    def impossible(rho: float) -> bool:
        return unreachable(team, pairs, work, rho * full, deadline,
                           _allowed_at(team, work, beta, ub, index, rho))

    low, high = 1.0, 1.0
    if impossible(1.0):
        high = 2.0
        while impossible(high) and high < 64:
            low, high = high, high * 2
        while high - low > tolerance and _wallclock.perf_counter() < deadline:
            mid = (low + high) / 2
            if impossible(mid):
                low = mid
            else:
                high = mid
    return OnlineBound(ratio=low, optimum_at_most=full,
                       unusable=[i for i, row in enumerate(beta) if min(row) > low],
                       prefix_optima=[ub[e] for e in sorted(ub)], seconds=_wallclock.perf_counter() - started)


def _short_schedule(team: Sequence[Machine], pre: Sequence[float], work: float, start: Sequence[int] | None,
                    steps: int, until: float) -> float:
    """The makespan of a short schedule of the programs released at ``pre``:
    greedy (each program on the robot that ends first with it), or ``start``,
    improved and annealed (until ``until``)."""
    if start is None:
        per: list[list[float]] = [[] for _ in team]
        greedy: list[int] = []
        for r in pre:
            i = min(range(len(team)), key=lambda i: finish(team[i], per[i] + [r], work))
            per[i].append(r)
            greedy.append(i)
        start = greedy
    up, placed = improve(team, pre, work, start, until)
    return min(up, anneal(team, pre, work, placed, steps=min(steps, 500 * len(pre) * len(team)), deadline=until)[0])


def _allowed_at(team: Sequence[Machine], work: float, beta: Sequence[Sequence[float]], ub: dict[int, float],
                index: dict[float, int], rho: float) -> Allowed:
    """Within rho, robot i takes a program of [a, b) only if it alone would end by
    rho * OPT(P), P the prefix up to b, and q of them only if q released together
    at a would (the first of their releases; processor sharing, as the bounds).
    ``beta[i][j]``: the least rho from which program j may go to robot i;
    ``ub``: a schedule's makespan per prefix (by its last program);
    ``index``: a release time's first program."""
    cache: dict[tuple[float, float], tuple[list[int], list[bool]]] = {}

    def allowed(a: float, b: float) -> tuple[list[int], list[bool]]:
        got = cache.get((a, b))
        if got is None:
            ia, ib = index[a], index[b]
            limit = rho * ub[ib - 1] if ib > ia else math.inf
            caps = []
            for m, row in zip(team, beta):
                q = sum(1 for x in row[ia:ib] if x <= rho)
                while q > 0 and a + work / rate(m, q) > limit:
                    q -= 1
                caps.append(q)
            got = cache[(a, b)] = (caps, [min(row[ib:], default=math.inf) <= rho for row in beta])
        return got
    return allowed
