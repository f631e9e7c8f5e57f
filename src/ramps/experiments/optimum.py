"""The exact optimum of a several-origins scenario, where a search can prove it.

Its lower bounds are in ``ramps.experiments.optimum_bounds``; what online
placements can guarantee, in ``ramps.experiments.optimum_online``.

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
- a lower bound stronger than the sweep's (``window_bound``, in
  ``ramps.experiments.optimum_bounds``, with the third property of
  processor sharing it rests on);
- the search above, cut as soon as it finds a schedule that reaches the
  lower bound, and stopped at the time limit with what it has: the best
  schedule, the best bound, and the gap between them.
"""

from __future__ import annotations

import heapq
import math
import random
import time as _wallclock
from typing import Callable, Sequence

import msgspec

from ramps.experiments.metrics import Machine, rate
from ramps.experiments.optimum_bounds import simple_bound, window_bound

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
        if _bound(ends, len(team), rel, j, waves, best) >= best - _EPS:
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



def _bound(ends: Callable[[int, int, float], float], robots: int, rel: Sequence[float], j: int,
           waves: Sequence[int], best: float) -> float:
    """No placement of programs j.. ends before this (see the module docstring):
    for j and each later wave start k, programs k.. released together at rel[k]
    beside those placed (those between are left out: a robot never ends earlier
    with more), given greedily to the robot that ends first with one more.
    ``ends(i, extra, at)``: when robot i ends with ``extra`` more released at ``at``."""
    def bound_from(k: int) -> float:
        at = rel[k]
        extra = [0] * robots
        worst = max(ends(i, 0, at) for i in range(robots))
        heap = [(ends(i, 1, at), i) for i in range(robots)]
        heapq.heapify(heap)
        for _ in range(len(rel) - k):
            t, i = heapq.heappop(heap)
            extra[i] += 1
            worst = max(worst, t)
            if worst >= best - _EPS:
                break
            heapq.heappush(heap, (ends(i, extra[i] + 1, at), i))
        return worst

    worst = bound_from(j)
    for k in waves:
        if worst >= best - _EPS:
            break
        if k > j:
            worst = max(worst, bound_from(k))
    return worst


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
        move = _propose(rng, assign, robots)
        if move is None:
            continue
        k, i, j, q = move
        _exchange(per, k, i, j, q)
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
            _exchange(per, k, j, i, q)
    return best, best_assign



def _propose(rng: random.Random, assign: Sequence[int], robots: int) -> tuple[int, int, int, int | None] | None:
    """A random change for ``anneal``: (k, i, j, None) moves program k from robot
    i to robot j, (k, i, j, q) swaps it with program q of robot j; None when the
    draw lands on k's own robot."""
    k = rng.randrange(len(assign))
    i = assign[k]
    if rng.random() < 0.5:  # move k to robot j
        j = rng.randrange(robots)
        return None if j == i else (k, i, j, None)
    q = rng.randrange(len(assign))  # swap k with q on robot j
    j = assign[q]
    return None if j == i else (k, i, j, q)


def _exchange(per: list[list[int]], k: int, i: int, j: int, q: int | None) -> None:
    """Program k from robot i's list to robot j's, and q (if any) from j's to i's;
    the same call with i and j exchanged undoes it."""
    per[i].remove(k)
    if q is not None:
        per[j].remove(q)
        per[i].append(q)
    per[j].append(k)


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
