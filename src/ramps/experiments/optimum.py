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

``solve`` puts it together for one scenario, and stays within a time limit:

- an upper bound: the oracle's placement (or any given one), improved by a
  local search that moves or swaps programs off the robot that ends last
  (``improve``), then, unless the bound below already meets it, by simulated
  annealing (``anneal``, a fixed seed and number of steps, at most half the
  time left);
- a lower bound stronger than the sweep's (``window_bound``): for two release
  times t1 < t2, the programs released in [t1, t2) have run for at most
  t2 - t1 seconds at t2, so at least ``work - (t2 - t1) * speed`` of each is
  left, and together they did at most ``(t2 - t1) * x * rate(m, x)`` (they
  shared the robot); a robot given x of them and y of those released at or
  after t2 ends no earlier than processor sharing from t2 of y whole programs
  and x programs left as favourably as those two limits allow
  (``shared_window_end``; ``window_end`` is the first limit alone). Whether the team can split the
  two kinds so that every robot ends by T is a two-dimensional knapsack over
  robots (exact, by dynamic programming); the smallest feasible T is the
  bound. Besides the two properties above it assumes a third, checked the
  same way: a robot never ends earlier when a program has more work left;
- the search above, cut as soon as it finds a schedule that reaches the
  lower bound, and stopped at the time limit with what it has: the best
  schedule, the best bound, and the gap between them.
"""

from __future__ import annotations

import heapq
import math
import time as _wallclock
from typing import Callable, Sequence

import msgspec

from ramps.experiments.metrics import Machine, optimal_allocation, rate

_EPS = 1e-9


def finish(m: Machine, releases: Sequence[float], work: float) -> float:
    """When the last of programs released at ``releases`` (sorted) ends on ``m``."""
    t, last, i, n = 0.0, 0.0, 0, len(releases)
    left: list[float] = []
    while i < n or left:
        nxt = releases[i] if i < n else float("inf")
        if left:
            r = rate(m, len(left))
            first = min(left)
            if t + first / r <= nxt:
                t += first / r
                left = [x - first for x in left if x - first > _EPS]
                last = t
                continue
            done = (nxt - t) * r
            left = [x - done for x in left]
        t = nxt
        left.append(work)
        i += 1
    return last


def exact_optimum(team: Sequence[Machine], releases: Sequence[float], work: float, upper: float,
                  max_nodes: int = 200_000, lower: float = 0.0,
                  deadline: float | None = None) -> tuple[float, bool, int]:
    """(best makespan found, whether it is proven optimal, placements visited).

    ``upper`` is the makespan of a feasible schedule (the oracle's); the
    result is never above it. ``lower`` is a known lower bound: a schedule
    that reaches it ends the search, proven. ``deadline`` (a
    ``time.perf_counter()`` instant) stops it like ``max_nodes`` does."""
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

    # where a new wave of releases starts: the bound also tries those
    waves = [k for k in range(1, n) if rel[k] - rel[k - 1] > 0.06]

    def bound_from(k: int) -> float:
        """Programs k.. released together at rel[k], beside those placed
        (those between are left out: a robot never ends earlier with more)."""
        at = rel[k]
        extra = [0] * len(team)
        worst = max(ends(i, 0, at) for i in robots)
        heap = [(ends(i, 1, at), i) for i in robots]
        heapq.heapify(heap)
        for _ in range(n - k):
            t, i = heapq.heappop(heap)
            extra[i] += 1
            worst = max(worst, t)
            if worst >= best - _EPS:
                break
            heapq.heappush(heap, (ends(i, extra[i] + 1, at), i))
        return worst

    def bound(j: int) -> float:
        """No placement of programs j.. ends before this (see the module docstring)."""
        worst = bound_from(j)
        for k in waves:
            if worst >= best - _EPS:
                break
            if k > j:
                worst = max(worst, bound_from(k))
        return worst

    def search(j: int) -> bool:
        """False once the node budget is spent."""
        nonlocal best, nodes
        nodes += 1
        if nodes > max_nodes or (deadline is not None and nodes % 256 == 0 and _wallclock.perf_counter() > deadline):
            return False
        if best <= lower + _EPS:
            return True  # nothing can beat the bound
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


# ------------------------------------------------------- upper bound: local search
def makespan_of(team: Sequence[Machine], releases: Sequence[float], work: float,
                assignment: Sequence[int]) -> float:
    """The makespan of placing program k (in ``releases`` order) on robot ``assignment[k]``."""
    per: list[list[float]] = [[] for _ in team]
    for r, a in zip(releases, assignment):
        per[a].append(r)
    return max((finish(m, sorted(p), work) for m, p in zip(team, per)), default=0.0)


def improve(team: Sequence[Machine], releases: Sequence[float], work: float, assignment: Sequence[int],
            deadline: float | None = None) -> tuple[float, list[int]]:
    """A local optimum near ``assignment``: while moving one program off the
    robot that ends last, or swapping it with one of another robot's,
    lowers the larger of the two robots' ends below the makespan, do the best
    such change. Returns (makespan, assignment)."""
    rel = list(releases)
    per: list[list[int]] = [[] for _ in team]  # program indices per robot
    for k, a in enumerate(assignment):
        per[a].append(k)

    def end(i: int, ks: Sequence[int]) -> float:
        return finish(team[i], sorted(rel[k] for k in ks), work)

    ends = [end(i, per[i]) for i in range(len(team))]
    while deadline is None or _wallclock.perf_counter() < deadline:
        top = max(ends)
        i = ends.index(top)
        change: tuple[float, int, int, int | None] | None = None
        moved: set[float] = set()  # programs released together are interchangeable
        for k in per[i]:
            if rel[k] in moved or (deadline is not None and _wallclock.perf_counter() > deadline):
                continue
            moved.add(rel[k])
            without = [q for q in per[i] if q != k]
            seen: set[tuple] = set()  # so are robots of the same kind holding the same programs
            for j in range(len(team)):
                key = (team[j], tuple(sorted(rel[q] for q in per[j])))
                if j == i or key in seen:
                    continue
                seen.add(key)
                new = max(end(i, without), end(j, per[j] + [k]))
                if new < top - _EPS and (change is None or new < change[0]):
                    change = (new, k, j, None)
                for q in per[j]:  # or swap it with a program released later
                    if rel[q] <= rel[k] + _EPS:
                        continue
                    new = max(end(i, without + [q]), end(j, [p for p in per[j] if p != q] + [k]))
                    if new < top - _EPS and (change is None or new < change[0]):
                        change = (new, k, j, q)
        if change is None:
            break
        _, k, j, swap = change
        per[i].remove(k)
        per[j].append(k)
        if swap is not None:
            per[j].remove(swap)
            per[i].append(swap)
        ends[i], ends[j] = end(i, per[i]), end(j, per[j])
    out = [0] * len(rel)
    for i, ks in enumerate(per):
        for k in ks:
            out[k] = i
    return max(ends, default=0.0), out


def anneal(team: Sequence[Machine], releases: Sequence[float], work: float, assignment: Sequence[int],
           *, steps: int = 200_000, deadline: float | None = None, seed: int = 0,
           temperature: float = 1.0) -> tuple[float, list[int]]:
    """A better schedule by simulated annealing from ``assignment``: move one
    program to another robot, or swap two programs of two robots; keep the
    change if the makespan (plus a thousandth of the three latest ends, so
    that moves off a robot that is not the last one count too) does not grow,
    else with probability ``exp(-growth / temperature)``, the temperature
    falling linearly to nothing over ``steps``, or by ``deadline`` if that comes
    first (a search the clock stops still ends cool).
    Returns the best (makespan, assignment) seen. ``improve`` stops at the
    first local optimum; this one climbs out: on the open staggered sweep
    scenarios it found schedules 3-8% shorter than improve and the branch
    and bound in 10 s, within 0-1.3% of the bound in 10 of 11 (2026-11-26)."""
    import random

    rel = list(releases)
    n, robots = len(rel), len(team)
    if n == 0 or robots < 2:
        return makespan_of(team, rel, work, assignment), list(assignment)
    rng = random.Random(seed)
    assign = list(assignment)
    per: list[list[int]] = [[] for _ in team]
    for k, a in enumerate(assign):
        per[a].append(k)

    def end(i: int) -> float:
        return finish(team[i], sorted(rel[k] for k in per[i]), work) if per[i] else 0.0

    def cost(ends: list[float]) -> float:
        top = heapq.nlargest(3, ends)
        return top[0] + 1e-3 * sum(top)

    ends = [end(i) for i in range(robots)]
    cur = cost(ends)
    best, best_assign = max(ends), list(assign)
    t0 = _wallclock.perf_counter()
    done = 0.0  # how far through: steps, or the time to the deadline if that is further
    for step in range(steps):
        if step % 256 == 0:
            done = step / steps
            if deadline is not None:
                now = _wallclock.perf_counter()
                if now > deadline:
                    break
                done = max(done, (now - t0) / max(deadline - t0, 1e-9))
        temp = temperature * (1.0 - done) + 1e-3  # cools to the end, whichever ends it
        k = rng.randrange(n)
        i = assign[k]
        if rng.random() < 0.5:  # move k to robot j
            j = rng.randrange(robots)
            if j == i:
                continue
            q = None
            per[i].remove(k)
            per[j].append(k)
        else:  # swap k with q on robot j
            q = rng.randrange(n)
            j = assign[q]
            if j == i:
                continue
            per[i].remove(k)
            per[j].remove(q)
            per[i].append(q)
            per[j].append(k)
        new = list(ends)
        new[i], new[j] = end(i), end(j)
        c = cost(new)
        if c <= cur or rng.random() < math.exp((cur - c) / temp):
            assign[k] = j
            if q is not None:
                assign[q] = i
            ends, cur = new, c
            if max(ends) < best - _EPS:
                best, best_assign = max(ends), list(assign)
        else:  # undo
            per[j].remove(k)
            per[i].append(k)
            if q is not None:
                per[i].remove(q)
                per[j].append(q)
    return best, best_assign


# ------------------------------------------------------- lower bound: two windows
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


def _window_pairs(rel: Sequence[float], single: bool) -> list[tuple[float, float, int, int]]:
    """(a, b, programs in [a, b), programs at or after b) for wave starts a < b,
    and with ``single`` also (b, b, 0, programs at or after b)."""
    starts = _windows(rel)
    pairs = [(a, b, sum(1 for r in rel if a <= r < b), sum(1 for r in rel if r >= b))
             for ia, a in enumerate(starts) for b in starts[ia + 1:]]
    if single:
        pairs += [(b, b, 0, sum(1 for r in rel if r >= b)) for b in starts]
    return pairs


def _unreachable(team: Sequence[Machine], pairs: Sequence[tuple[float, float, int, int]], work: float,
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


def _windows(releases: Sequence[float]) -> list[float]:
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
    pairs = _window_pairs(rel, single=allowed is not None)

    def unreachable(target: float) -> bool:
        return _unreachable(team, pairs, work, target, deadline, allowed)

    if not pairs:
        return low
    if unreachable(high * (1 - tolerance)):
        return high * (1 - tolerance)
    while high - low > tolerance * high:
        if deadline is not None and _wallclock.perf_counter() > deadline:
            break
        mid = (low + high) / 2
        if unreachable(mid):
            low = mid
        else:
            high = mid
    return low


# ------------------------------------------------------- one scenario
class OptimumResult(msgspec.Struct, kw_only=True, frozen=True):
    """What ``solve`` knows about one scenario's optimum."""

    #: the makespan of the best schedule found (an upper bound on the optimum)
    best: float
    #: no schedule ends before this
    bound: float
    #: best is the optimum (the bound reaches it, or the search finished)
    proven: bool
    #: placements the search visited, and seconds spent
    nodes: int
    seconds: float
    #: "bound" (the bound reached the schedule), "search" (the search finished),
    #: "time" or "nodes" (stopped: not proven)
    how: str

    @property
    def gap(self) -> float:
        """How far the best schedule may be above the optimum (0 when proven)."""
        return 0.0 if self.proven else self.best / self.bound - 1.0


def solve(team: Sequence[Machine], releases: Sequence[float], work: float, assignment: Sequence[int],
          *, time_limit: float = 10.0, max_nodes: int = 2_000_000, tolerance: float = 1e-6,
          anneal_steps: int = 100_000) -> OptimumResult:
    """The optimum of one scenario where it can be proven within ``time_limit``
    seconds, else the best schedule and bound found. ``assignment`` is a
    feasible placement to start from (program k in sorted release order on
    robot ``assignment[k]``), e.g. the oracle's."""
    if len(assignment) != len(releases) or any(not 0 <= a < len(team) for a in assignment):
        raise ValueError(f"assignment must give each of the {len(releases)} programs a robot "
                         f"0..{len(team) - 1}, got {list(assignment)[:10]}")
    if work <= 0 or time_limit < 0:
        raise ValueError(f"work must be > 0 and time_limit >= 0 (got {work}, {time_limit})")
    started = _wallclock.perf_counter()
    deadline = started + time_limit
    rel = sorted(releases)

    def done(best: float, bound: float, proven: bool, nodes: int, how: str) -> OptimumResult:
        return OptimumResult(best=best, bound=min(bound, best) if proven else bound, proven=proven, nodes=nodes,
                             seconds=_wallclock.perf_counter() - started, how=how)

    if not rel:
        return done(0.0, 0.0, True, 0, "bound")
    upper, placed = improve(team, rel, work, assignment, deadline)
    lower = simple_bound(team, rel, work)
    if upper <= lower * (1 + tolerance):
        return done(upper, lower, True, 0, "bound")
    lower = max(lower, window_bound(team, rel, work, lower, upper, deadline, tolerance))
    if upper <= lower * (1 + tolerance) * (1 + tolerance):
        return done(upper, lower, True, 0, "bound")
    if anneal_steps > 0:  # a better schedule (the search below then cuts more), in at most half the time left
        left = deadline - _wallclock.perf_counter()
        steps = min(anneal_steps, 500 * len(rel) * len(team))  # small teams need few
        upper = min(upper, anneal(team, rel, work, placed, steps=steps,
                                  deadline=_wallclock.perf_counter() + max(0.0, left) / 2)[0])
        if upper <= lower * (1 + tolerance) * (1 + tolerance):
            return done(upper, lower, True, 0, "bound")
    best, finished, nodes = exact_optimum(team, rel, work, upper, max_nodes=max_nodes, lower=lower,
                                          deadline=deadline)
    if finished:
        return done(best, best if best > lower * (1 + tolerance) else lower, True, nodes, "search")
    how = "time" if _wallclock.perf_counter() > deadline else "nodes"
    return done(best, lower, False, nodes, how)


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
    starts = _windows(rel)
    wave_end = [max(k for k in range(n) if rel[k] < min((s for s in starts if s > rel[j]), default=math.inf))
                for j in range(n)]

    def schedule(k: int, start: Sequence[int] | None, until: float) -> float:
        """A short schedule of the first k programs: greedy (each program on the robot
        that ends first with it), or ``start``, improved and annealed (until ``until``)."""
        pre = rel[:k]
        if start is None:
            per: list[list[float]] = [[] for _ in team]
            greedy: list[int] = []
            for r in pre:
                i = min(range(len(team)), key=lambda i: finish(team[i], per[i] + [r], work))
                per[i].append(r)
                greedy.append(i)
            start = greedy
        up, placed = improve(team, pre, work, start, until)
        return min(up, anneal(team, pre, work, placed, steps=min(steps, 500 * k * len(team)), deadline=until)[0])

    # a third of the time for the prefixes' schedules, a third for the whole one's, a third to bisect
    waves_ends = sorted(set(wave_end))
    ub: dict[int, float] = {}
    for e in waves_ends:
        share = time_limit / 3 / len(waves_ends)
        ub[e] = schedule(e + 1, None, min(deadline, _wallclock.perf_counter() + share))
    full = ub[n - 1]
    if assignment is not None:
        full = min(full, schedule(n, assignment, min(deadline, _wallclock.perf_counter() + time_limit / 3)))
    if upper is not None:
        full = min(full, upper)
    ub[n - 1] = full
    # program j may go to robot i within rho from rho = beta[i][j] on
    beta = [[(rel[j] + work / rate(m, 1)) / ub[wave_end[j]] for j in range(n)] for m in team]
    index = {r: k for k, r in reversed(list(enumerate(rel)))}  # a release time -> its first program

    def allowed_at(rho: float) -> Allowed:
        """Within rho, robot i takes a program of [a, b) only if it alone would end by
        rho * OPT(P), P the prefix up to b, and q of them only if q released together
        at a would (the first of their releases; processor sharing, as the bounds)."""
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

    pairs = _window_pairs(rel, single=True)

    def impossible(rho: float) -> bool:
        return _unreachable(team, pairs, work, rho * full, deadline, allowed_at(rho))

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
