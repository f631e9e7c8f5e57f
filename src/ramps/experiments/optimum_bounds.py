"""Lower bounds on a several-origins scenario's optimum (``ramps.experiments.optimum``).

How this works: ``simple_bound`` is the sweep's: the programs released at or
after r started together at r on an idle team, for every release time r.
``window_bound`` is stronger: for two release times t1 < t2, the programs
released in [t1, t2) have run for at most t2 - t1 seconds at t2, so at
least ``work - (t2 - t1) * speed`` of each is left, and together they did at
most ``(t2 - t1) * x * rate(m, x)`` (they shared the robot); a robot given x
of them and y of those released at or after t2 ends no earlier than
processor sharing from t2 of y whole programs and x programs left as
favourably as those two limits allow (``shared_window_end``; ``window_end``
is the first limit alone). Whether the team can split the two kinds so that
every robot ends by T is a two-dimensional knapsack over robots (exact, by
dynamic programming: ``_split_fits``); the smallest feasible T is the
bound, found by bisection. ``allowed`` keeps each kind of program off
robots it names (``ramps.experiments.optimum_online`` uses it).

The bounds rest on three properties of processor sharing that
``tests/test_optimum.py`` checks on thousands of random robots but that are
not proven here: a robot never ends earlier with more programs, nor when its
programs still to come are all released at the first of their times, nor
when a program has more work left.
"""

from __future__ import annotations

import time as _wallclock
from typing import Callable, Sequence

from ramps.experiments.metrics import Machine, optimal_allocation, rate

_EPS = 1e-9


def window_end(m: Machine, x: int, left: float, y: int, at: float, work: float) -> float:
    """When ``m`` ends if at time ``at`` it holds ``x`` programs with ``left``
    work each and ``y`` whole ones (processor sharing, nothing else after)."""
    left = min(work, max(0.0, left))
    if y == 0:
        return at + left / rate(m, x) if x and left > 0 else 0.0
    if x == 0 or left <= 0:
        return at + work / rate(m, y)
    return at + left / rate(m, x + y) + (work - left) / rate(m, y)


def shared_window_end(m: Machine, x: int, span: float, y: int, at: float, work: float) -> float:
    """No earlier than ``m`` ends if ``x`` programs were released within the
    ``span`` seconds before ``at`` and ``y`` more at ``at`` (processor sharing,
    nothing else after). Stronger than ``window_end`` with ``work - span *
    speed`` left: the x programs also *shared* the robot during the span.

    Each ran at most at one core (``done <= span * speed``) and together at
    most ``x * rate(m, x)`` (a robot's programs progress fastest all
    present, and ``n * rate(m, n)`` grows with n). Of the ways to leave that
    much work, the one that ends first is taken: with processor sharing the
    robot ends ``∫ du / rate(m, n(u))`` after ``at``, n(u) the programs with
    more than u left. Without y, ``1 / rate(m, n) / n`` falls with n, so
    equal work left ends first; with y >= 1, ``1 / rate(m, y + k)`` is convex
    in k, so the x programs' work left spread as evenly as the floor
    allows over the levels the y alone span ends first (Jensen)."""
    if x == 0 or span <= 0.0:
        return window_end(m, x, work, y, at, work) if x else (at + work / rate(m, y) if y else 0.0)
    cap = min(work, span * m.speed)  # the most one program did
    done = min(x * cap, span * x * rate(m, x))  # the most they all did
    if y == 0:
        left = work - done / x
        return at + left / rate(m, x) if left > _EPS else 0.0
    floor_left = work - cap  # every program has at least this left
    level = (x * cap - done) / cap if cap > 0 else float(x)  # programs above the floor, on average
    k = min(x, int(level))
    f = level - k
    above = (1.0 - f) / rate(m, y + k) + (f / rate(m, y + k + 1) if f > _EPS else 0.0)
    return at + floor_left / rate(m, x + y) + cap * above


def _split_fits(team: Sequence[Machine], t1: float, t2: float, nx: int, ny: int, work: float,
                target: float, x_cap: Sequence[int] | None = None, y_ok: Sequence[bool] | None = None) -> bool:
    """Can the team take nx programs released in [t1, t2) and ny released at
    or after t2 with every robot's ``window_end`` at most ``target``?
    dp[y] = the most window programs the robots so far take beside y late ones.
    ``x_cap[i]``: robot i takes at most that many window programs;
    ``y_ok[i]`` False: none of the late ones."""
    none = -1
    dp = [0] + [none] * ny
    tables: dict[tuple[Machine, int, bool], list[int]] = {}
    for i, m in enumerate(team):
        xc = nx if x_cap is None else min(nx, x_cap[i])
        yo = y_ok is None or y_ok[i]
        tab = tables.get((m, xc, yo))
        if tab is None:
            span = t2 - t1
            tab = []
            for y in range(ny + 1 if yo else 1):
                if shared_window_end(m, 0, span, y, t2, work) > target:
                    break
                x = xc  # the most that fit; the DP lets a robot take fewer (sound even if the bound dips with x)
                while x > 0 and shared_window_end(m, x, span, y, t2, work) > target:
                    x -= 1
                tab.append(x)
            tables[(m, xc, yo)] = tab
        new = [none] * (ny + 1)
        for y, got in enumerate(dp):
            if got == none:
                continue
            for extra in range(min(len(tab), ny - y + 1)):
                v = min(nx, got + tab[extra])
                if v > new[y + extra]:
                    new[y + extra] = v
        dp = new
    return dp[ny] >= nx


#: how many programs released in [a, b) each robot may take, and whether it may take those
#: released at or after b
Allowed = Callable[[float, float], tuple[Sequence[int], Sequence[bool]]]


def window_pairs(rel: Sequence[float], single: bool) -> list[tuple[float, float, int, int]]:
    """(a, b, programs in [a, b), programs at or after b) for wave starts a < b,
    and with ``single`` also (b, b, 0, programs at or after b)."""
    starts = wave_starts(rel)
    pairs = [(a, b, sum(1 for r in rel if a <= r < b), sum(1 for r in rel if r >= b))
             for ia, a in enumerate(starts) for b in starts[ia + 1:]]
    if single:
        pairs += [(b, b, 0, sum(1 for r in rel if r >= b)) for b in starts]
    return pairs


def unreachable(team: Sequence[Machine], pairs: Sequence[tuple[float, float, int, int]], work: float,
                 target: float, deadline: float | None, allowed: Allowed | None) -> bool:
    """Some pair of windows shows that no schedule ends by ``target`` (False
    when the deadline passes first: not shown)."""
    for a, b, nx, ny in pairs:
        if deadline is not None and _wallclock.perf_counter() > deadline:
            return False
        x_cap, y_ok = allowed(a, b) if allowed is not None else (None, None)
        if not _split_fits(team, a, b, nx, ny, work, target, x_cap, y_ok):
            return True
    return False


def wave_starts(releases: Sequence[float]) -> list[float]:
    """Release times that start a new wave (more than 0.06 s after the one before)."""
    rel = sorted(releases)
    return rel[:1] + [b for a, b in zip(rel, rel[1:]) if b - a > 0.06]


def simple_bound(team: Sequence[Machine], releases: Sequence[float], work: float) -> float:
    """The sweep's bound: programs released at or after r, started together
    at r on an idle team, for every release time r."""
    rel = sorted(releases)
    best = 0.0
    for idx, r in enumerate(rel):
        if idx and rel[idx - 1] == r:
            continue
        best = max(best, r + optimal_allocation(len(rel) - idx, team, work)[1])
    return best


def window_bound(team: Sequence[Machine], releases: Sequence[float], work: float, low: float, high: float,
                 deadline: float | None = None, tolerance: float = 1e-6, allowed: Allowed | None = None) -> float:
    """The largest T in [low, high] (to ``tolerance``, relative) such that no
    schedule ends by T, as some pair of windows shows; ``low`` if none does.
    ``high`` is a schedule's makespan, so the bound stays below it: a bound
    within the tolerance of it proves that schedule optimal. With ``allowed``,
    of the schedules that keep each kind of program off the robots it names."""
    rel = sorted(releases)
    pairs = window_pairs(rel, single=allowed is not None)

    def shown(target: float) -> bool:
        return unreachable(team, pairs, work, target, deadline, allowed)

    if not pairs:
        return low
    if shown(high * (1 - tolerance)):
        return high * (1 - tolerance)
    while high - low > tolerance * high:
        if deadline is not None and _wallclock.perf_counter() > deadline:
            break
        mid = (low + high) / 2
        if shown(mid):
            low = mid
        else:
            high = mid
    return low

