"""Programs an origin receives at one instant, placed as a whole.

How this works: with ``Origin.bursts`` on, ``Origin.submit`` holds each
program in ``Origin.held`` instead of placing it, and ``place_held`` places
what is held when the driver ends its batch of events (``Node.flush``, or
the next ``Node.tick``, which ``Node.next_deadline`` makes due at once): the
simulator ends a batch after the programs submitted at one instant, the
runtime after each round of its queue (a ``Team.map``, a burst of submits).
Without it every program is placed as it comes, a burst of one.

- A policy that does not plan (``Policy.plans`` False: the paper's, the
  baselines) takes a burst's programs one by one in submission order, as
  if each came alone.
- ``ramps`` takes programs with a deadline first, earliest deadline first,
  each as if alone. The rest, if they are not all alike (a burst of equal
  programs is placed one by one: where each ends first is then as good as
  any plan) and at most ``PLAN_MAX``, are planned together: for each, the
  pool it would share on every candidate (``RampsPolicy.pools``: the slots
  of its accelerator where the robot has that kind, else the robot's cores,
  with the work left of what runs there; the ``PLAN_POOLS`` where it alone
  would end first); a first placement longest first, each where its pool
  would end first; then moves and swaps of the programs of the pool that
  ends last, while the burst ends sooner (or as soon with the pools' ends
  more even), at most ``PLAN_STEPS`` per program. Each is then offered,
  longest first, to the host of its plan, priced as ``choose`` prices any
  (``PlacementRequest.prefer``): its booking counts before the next is
  priced, and its host's admission checks the estimate as for any offer,
  with a time budget of at least the plan's end. A larger burst is placed
  longest first (each program's time alone computed once per distinct
  request), each where it ends first.

Teammates' bursts of the same instant (``ramps.core.claims``) come as
``Origin.claimed``: their work counts on the pools they claimed, and a
burst of equal programs is then planned too; a larger burst is then planned
``PLAN_MAX`` programs at a time, in the order submitted, each part after the
bookings of those before it.

A pool's end with the programs ``works`` planned there: when the largest of
them ends under processor sharing with the rest and with the work left of
those already there (``shared_finish_time``; one whose work the view does
not know counts as the largest), plus the longest T_comm of them; with
``RampsConfig.place_by`` "pool_end", when the last program there ends,
those already there included (a plan then weighs the delay it brings
them). Pure
functions and the origin's own objects: no clock, no I/O.
"""

from __future__ import annotations

import heapq
from collections.abc import Callable
from typing import TYPE_CHECKING, Protocol

import msgspec

from ramps.core.config import RampsConfig
from ramps.core.cost import NetworkEstimate, shared_finish_time
from ramps.core.events import Action, Submit
from ramps.core.loadview import LoadView
from ramps.core.policy import Placement, PlacementRequest, Policy, Pool
from ramps.core.program import FINAL, AutonomousProgram

if TYPE_CHECKING:
    from ramps.core.links import Links

#: a burst of at most this many programs (of more than one kind) is planned
#: as a whole; a larger one is placed longest first, one by one
PLAN_MAX = 24
#: improvements the plan makes at most, per program planned
PLAN_STEPS = 2
#: the candidates a plan weighs for each program at most: those where it
#: alone would end first
PLAN_POOLS = 32


def pool_end(pool: Pool, works: list[float], comms: list[float], whole: bool = False) -> float:
    """Seconds until the last of ``works`` placed on ``pool`` together ends,
    and its result is back (0 for none); ``whole``: until the last program
    of the pool ends, those already there included (``RampsConfig.place_by``
    "pool_end")."""
    if not works:
        return 0.0
    top = max(works)
    if whole and pool.known:
        top = max(top, max(pool.known))
    others = list(pool.known)
    others += [top] * pool.unknown
    others += works
    others.remove(top)  # the largest of works, or of those already there (whole)
    return shared_finish_time(top, others, pool.cores, pool.speed, pool.background, pool.weight) + max(comms)


def plan(options: list[dict[tuple[str, str], Pool]], whole: bool = False
         ) -> tuple[list[tuple[str, str]], dict[tuple[str, str], float]]:
    """The pool of each program (``options[i]``: its pools by (robot, kind),
    ``RampsPolicy.pools``) that makes the burst end soonest, by the search
    of the module docstring, and each pool's end then. ``whole``: a pool
    ends when the last of its programs does, those already there included
    (``pool_end``), and the first placement breaks ties by when the
    burst's programs there end."""
    pools: dict[tuple[str, str], Pool] = {}
    for opts in options:
        for key, p in opts.items():
            pools.setdefault(key, p)
    on: dict[tuple[str, str], list[int]] = {key: [] for key in pools}
    known: dict[tuple[object, ...], float] = {}  # alike programs make the same ends over and over

    def end(key: tuple[str, str], jobs: list[int], whole: bool = whole) -> float:
        works = tuple([options[j][key].work for j in jobs])
        comms = tuple([options[j][key].comm for j in jobs])
        memo = (key, whole, works, comms)
        e = known.get(memo)
        if e is None:
            e = known[memo] = pool_end(pools[key], list(works), list(comms), whole)
        return e

    alone = [min(end(key, [j], False) for key in opts) for j, opts in enumerate(options)]
    where: list[tuple[str, str]] = [("", "")] * len(options)
    for j in sorted(range(len(options)), key=lambda j: -alone[j]):
        best = None
        for key in options[j]:
            p = pools[key]
            # whole: then when the burst's own programs there end
            rank = (end(key, on[key] + [j]), end(key, on[key] + [j], False) if whole else 0.0,
                    (p.unknown + len(p.known) + len(on[key]) + 1.0) / p.cores)
            if best is None or rank < best[0]:
                best = (rank, key)
        assert best is not None
        where[j] = best[1]
        on[best[1]].append(j)
    ends = {key: end(key, jobs) for key, jobs in on.items()}
    for _ in range(PLAN_STEPS * len(options)):
        step = _improve(options, on, ends, end)
        if step is None:
            break
        for key, jobs in step.items():
            on[key] = jobs
            ends[key] = end(key, jobs)
            for j in jobs:
                where[j] = key
    return where, ends


def _improve(options: list[dict[tuple[str, str], Pool]], on: dict[tuple[str, str], list[int]],
             ends: dict[tuple[str, str], float], end: Callable[[tuple[str, str], list[int]], float]
             ) -> dict[tuple[str, str], list[int]] | None:
    """The best move of one program off the pool that ends last, or swap of
    one of them with a program elsewhere that may run there: the pools it
    changes, or None when none makes the burst end sooner, or as soon with
    a smaller sum of the squares of the pools' ends."""
    crit = max(ends, key=ends.__getitem__)
    squares = sum(e * e for e in ends.values())
    best_score, best = (ends[crit], squares), None
    for j in on[crit]:
        stay = [i for i in on[crit] if i != j]
        e_stay = end(crit, stay)
        for key in options[j]:
            if key == crit:
                continue
            tries = [{crit: stay, key: on[key] + [j]}]
            tries += [{crit: stay + [i], key: [x for x in on[key] if x != i] + [j]} for i in on[key] if crit in options[i]]
            for changed in tries:
                new = {k: e_stay if jobs is stay else end(k, jobs) for k, jobs in changed.items()}
                top = max([*new.values(), *(e for k, e in ends.items() if k not in changed)])
                score = (top, squares + sum(e * e - ends[k] * ends[k] for k, e in new.items()))
                if _better(score, best_score):
                    best_score, best = score, changed
    return best


def _better(a: tuple[float, float], b: tuple[float, float]) -> bool:
    """Whether the burst end and sum of squares ``a`` beat ``b`` by more than rounding."""
    eps = 1e-9
    if a[0] < b[0] * (1.0 - eps):
        return True
    return a[0] <= b[0] * (1.0 + eps) and a[1] < b[1] * (1.0 - eps)


class BurstOrigin(Protocol):
    """What ``place_held`` reads of ``ramps.core.origin.Origin``."""

    held: list[AutonomousProgram]
    #: (robot, accelerator kind) -> work teammates' bursts of the instant put there (``ramps.core.claims``)
    claimed: dict[tuple[str, str], list[float]]
    view: LoadView
    net: NetworkEstimate
    config: RampsConfig
    links: Links | None

    def policy_for(self, sub: Submit) -> Policy: ...

    def exclusions(self, ap: AutonomousProgram, now: float, out: list[Action]) -> frozenset[str] | None: ...

    def request(self, ap: AutonomousProgram, work: float, accel_work: float, left: float | None,
                prefer: tuple[str, float] = ("", 0.0)) -> PlacementRequest: ...

    def work_estimate(self, sub: Submit) -> float: ...

    def accelerator_work_estimate(self, sub: Submit) -> float: ...

    def place(self, ap: AutonomousProgram, now: float, out: list[Action], *, host: str | None = None,
              placement: Placement | None = None, prefer: tuple[str, float] = ("", 0.0)) -> None: ...


def place_held(origin: BurstOrigin, now: float, out: list[Action]) -> None:
    """Place the programs ``origin`` holds, as a whole (see the module
    docstring); one cancelled meanwhile is not placed."""
    held, origin.held = [ap for ap in origin.held if ap.state not in FINAL and ap.host is None], []
    first: list[AutonomousProgram] = []  # one by one, in submission order
    due: list[AutonomousProgram] = []  # with a deadline, earliest first
    together: dict[int, list[AutonomousProgram]] = {}  # by planning policy
    for ap in held:
        sub = ap.submit
        policy = origin.policy_for(sub)
        if not policy.plans or sub.local_only or origin.config.energy_weight > 0:
            first.append(ap)
        elif sub.deadline is not None:
            due.append(ap)
        else:
            together.setdefault(id(policy), []).append(ap)
    due.sort(key=lambda ap: ap.submit.deadline or 0.0)
    for ap in first + due:
        origin.place(ap, now, out)
    for group in together.values():
        _place_together(origin, group, now, out)


def _place_together(origin: BurstOrigin, group: list[AutonomousProgram], now: float, out: list[Action]) -> None:
    """Place ``group`` (no deadlines, one planning policy): planned when it
    is small and mixed, else longest first, one by one."""
    kinds: dict[tuple[object, ...], list[AutonomousProgram]] = {}
    for ap in group:
        kinds.setdefault(_alike(ap.submit), []).append(ap)
    claimed = origin.claimed
    if len(kinds) == 1 and not claimed:
        for ap in group:
            origin.place(ap, now, out)
        return
    if len(group) > PLAN_MAX and claimed:  # planned in turn, each part's bookings before the next
        for i in range(0, len(group), PLAN_MAX):
            _place_together(origin, group[i:i + PLAN_MAX], now, out)
        return
    policy = origin.policy_for(group[0].submit)
    links = origin.links.estimate if origin.links is not None else None
    if len(group) > PLAN_MAX:  # longest first: each kind's time alone, priced once
        alone = {}
        for key, aps in kinds.items():
            pools = policy.pools(_request(origin, aps[0]), origin.view, now, net=origin.net, links=links)
            alone[key] = min((pool_end(p, [p.work], [p.comm]) for p in pools), default=0.0)
        for ap in sorted(group, key=lambda ap: -alone[_alike(ap.submit)]):
            origin.place(ap, now, out)
        return
    planned, options = [], []
    priced: dict[tuple[object, ...], dict[tuple[str, str], Pool]] = {}  # alike programs share their pools
    for ap in group:
        exclude = origin.exclusions(ap, now, out)
        if exclude is None:
            continue  # nowhere it may go now: it waits, or failed
        key = (_alike(ap.submit), len(ap.checkpoint or b""), exclude)
        if key not in priced:
            priced[key] = _pools(origin, policy, ap, now, exclude, claimed, links)
        planned.append(ap)
        options.append(priced[key])
    where, ends = plan(options, origin.config.place_by == "pool_end")
    took = [pool_end(options[j][w], [options[j][w].work], [options[j][w].comm]) for j, w in enumerate(where)]
    last = max(ends.values())
    for j in sorted(range(len(planned)), key=lambda j: -took[j]):
        origin.place(planned[j], now, out, prefer=(where[j][0], last))


def _pools(origin: BurstOrigin, policy: Policy, ap: AutonomousProgram, now: float, exclude: frozenset[str],
           claimed: dict[tuple[str, str], list[float]], links: Callable[[str], NetworkEstimate] | None
           ) -> dict[tuple[str, str], Pool]:
    """The pools ``ap`` may share, by (robot, kind), with the teammates'
    claimed work on them: the ``PLAN_POOLS`` where it alone would end first."""
    pools = policy.pools(_request(origin, ap), origin.view, now, net=origin.net, exclude=exclude, links=links)
    if claimed:  # teammates' bursts of the instant, as work there
        pools = [msgspec.structs.replace(p, known=p.known + tuple(claimed[p.robot, p.kind]))
                 if (p.robot, p.kind) in claimed else p for p in pools]
    if len(pools) > PLAN_POOLS:
        pools = heapq.nsmallest(PLAN_POOLS, pools, key=lambda p: pool_end(p, [p.work], [p.comm]))
    return {(p.robot, p.kind): p for p in pools}


def _request(origin: BurstOrigin, ap: AutonomousProgram) -> PlacementRequest:
    sub = ap.submit
    return origin.request(ap, origin.work_estimate(sub), origin.accelerator_work_estimate(sub), None)


def _alike(sub: Submit) -> tuple[object, ...]:
    """What placement tells programs apart by: equal ones are interchangeable."""
    return (sub.program, sub.work, sub.accelerator, sub.accelerator_work, sub.cpu_fallback, sub.payload_size,
            sub.result_size, sub.memory, sub.policy)
