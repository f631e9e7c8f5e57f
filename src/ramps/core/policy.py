"""Placement policies: where an autonomous program goes.

Rules: a policy is a strategy object with one method, ``choose``, that reads
the origin's load view and returns a ``Placement``. It never changes the view
(the origin books the placement afterwards) and takes all randomness from
the ``rng`` it is given. Each origin holds its own policy instance, so each
robot decides for its own programs from its own view: there is no central
scheduler.

* ``paper``: the prototype of Valkov et al.: T_there = work / speed * (1 +
  utilisation), utilisation from the last report's CPU load (which saturates
  at 100%) plus bookings this robot made since that report; the next report
  overwrites the bookings; every executor, the local one included, costs the
  same T_comm (the prototype offloaded to its own executor through the same
  action protocol); ties are broken at random.
* ``ramps``: our default. Cost from run-queue length (8 stress processes look
  like 8, not like "100%"), ramps programs counted from bookings until a
  report proves it includes them, the share a program gets weighted by the
  host's scheduler weights (its workers at nice 10 yield to the robot's own
  software, see ``cost.program_share``), eq. (1) with T_comm for remote hosts only;
  costs within ``tie_tolerance`` are equal, and the tie goes to the least
  utilised robot, then to the one with less busy software of its own, then
  to the local one; the local robot, where a whole core is free for the
  program, ties with the best when within ``HOME_MARGIN`` of it. The host checks the origin's
  estimate when the request arrives (``expected_runnable``) and turns the
  program away if it is busier than the origin thought, which fixes the
  greedy "location thrashing" of several origins deciding on the same data.
  A program with a deadline (``PlacementRequest.deadline``) goes to the
  slowest host expected to finish within it (``DEADLINE_MARGIN``; best
  fit, which keeps the faster hosts for tighter
  programs, then the ties as above), else to the cheapest host if it is in
  time; its budget is then what the deadline leaves. No deadline places as
  before. ``Placement.late`` says that no host is expected in time (the
  origin then applies the program's ``on_miss``). A program that can use
  an accelerator (``PlacementRequest.accelerator``) is priced by
  processor sharing of the slots of the robots that advertise that kind
  (``shared_finish_time`` with the work left of the programs there: as
  their host's report lists it, plus those this origin placed there since;
  from a host that lists none, those this origin placed there and its own
  work for the others) and by its CPU work on the others; the origin leaves
  the others out when it may not run on a CPU.
  With ``RampsConfig.energy_weight`` above 0, hosts are chosen by time and
  energy per unit of work, weighed (``battery.rank_by_energy``), and
  priced (time, budget) by time alone. With ``RampsConfig.place_by``
  "pool_end" (the default; no deadline nor energy weight), a host costs when the
  last program of its pool (``pool_finish_time``: those there by their
  work left, and the new one) would end, and costs within
  ``tie_tolerance`` go to the program's own earliest end, then as above;
  the budget is the best other host's cost so ranked. A burst (programs an origin
  gets at one instant) is planned as a whole (``plans``, ``pools``;
  ``ramps.core.burst``): ``choose`` then takes the host of the plan
  (``PlacementRequest.prefer``), with a budget of at least the plan's end.
  In a view of more robots than ``RampsConfig.placement_sample`` it prices
  a short list of the cheapest instead of every robot (``_priced``).
* ``round_robin``, ``random``, ``local_only``: baselines.
"""

from __future__ import annotations

import heapq
import math
import random
from typing import Any, Callable, ClassVar

import msgspec

from ramps.core.battery import rank_by_energy, unrank
from ramps.core.config import RampsConfig
from ramps.core.cost import NetworkEstimate, comm_time, pool_finish_time, program_share, shared_finish_time
from ramps.core.links import Links
from ramps.core.loadview import LoadView


#: how many of the cheapest hosts by count get the finer estimate by work left
REFINE = 16
#: seconds a large team's short list of candidates stands before the next
#: full scan (``RampsConfig.placement_sample``, ``RampsPolicy._priced``)
SHORT_LIST_FOR = 1.0
#: a program with a deadline goes to the slowest host expected to end it
#: this much earlier than its deadline (a fraction of its expected time);
#: 0: the slowest host in time, which keeps the most of the faster hosts
#: for tighter programs. A margin leaves room on the chosen host for
#: programs that come later; with a perfect view of the present a 50%
#: margin misses 9% more deadlines than none on the deadline family
#: (docs/lab/2026-11-27-accelerators-deadlines-gap.md)
DEADLINE_MARGIN = 0.0
#: this robot, where a whole core is free for the program, ties with the
#: best host when it ends the program within this fraction of that host's
#: time (the ties are then broken as any: least utilised, less busy
#: software, this robot): a teammate a little faster gains the program
#: little, and its core is what the other origins' next programs draw on,
#: which no origin sees coming (docs/lab/2026-11-27-battery-gap.md)
HOME_MARGIN = 0.05


class PlacementRequest(msgspec.Struct, frozen=True, kw_only=True):
    program_id: str
    work: float
    payload_size: int
    result_size: int
    #: seconds left before the program's deadline (None: none); ``ramps``
    #: keeps to the hosts expected to finish within it while there are any
    deadline: float | None = None
    #: the kind of accelerator the program runs on where a robot has one, and
    #: its work there (``ramps`` prices those robots by their slots,
    #: ``ramps.core.accelerators``); "" = CPUs only
    accelerator: str = ""
    accelerator_work: float = 0.0
    #: the host a burst's plan chose (``ramps.core.burst``), and when the plan
    #: has the burst end, seconds from now: ``ramps`` picks it while it is a
    #: candidate, priced as any, with a budget of at least what the plan leaves
    prefer: str = ""
    plan_end: float = 0.0


class Pool(msgspec.Struct, frozen=True, kw_only=True):
    """What a program placed on ``robot`` would share there (a burst's plan,
    ``ramps.core.burst``): its cores
    (``kind`` "") or its slots of one kind of accelerator."""

    robot: str
    kind: str
    cores: float
    speed: float
    background: float = 0.0
    weight: float = 1.0
    #: work left in the programs there whose work the view knows
    known: tuple[float, ...] = ()
    #: programs there whose work it does not know
    unknown: int = 0
    #: the program's work there, and T_comm to that robot
    work: float = 0.0
    comm: float = 0.0


class Placement(msgspec.Struct, frozen=True, kw_only=True):
    host: str
    #: runnable tasks the origin expects on the host (ramps negotiation)
    expected_runnable: float | None = None
    #: estimated seconds to completion there, for traces
    expected_time: float | None = None
    #: the longest computation on the host that still beats the best other
    #: candidate, seconds (ramps negotiation, see ``OffloadRequest``)
    time_budget: float | None = None
    #: the program has a deadline and no candidate is expected to meet it
    #: (this is the fastest); only policies that estimate times say so
    late: bool = False


class Policy:
    name: ClassVar[str] = ""
    #: whether hosts should check ``expected_runnable`` on arrival
    negotiates: ClassVar[bool] = False
    #: whether hosts publish prompt reports when their programs change
    #: (``RampsConfig.prompt_reports``); the paper's prototype did not
    shares_load: ClassVar[bool] = False
    #: whether an origin re-evaluates eq. (1) for its running programs and
    #: moves them (``RampsConfig.relocate``); the paper's prototype did not
    relocates: ClassVar[bool] = False
    #: whether an origin places a burst (programs submitted at one instant)
    #: as a whole, by ``pools`` (``ramps.core.burst``); others take a burst's
    #: programs one by one in submission order
    plans: ClassVar[bool] = False

    def choose(
        self,
        req: PlacementRequest,
        view: LoadView,
        now: float,
        rng: random.Random,
        *,
        net: NetworkEstimate,
        config: RampsConfig,
        exclude: frozenset[str] = frozenset(),
        links: Callable[[str], NetworkEstimate] | None = None,
    ) -> Placement:
        """``links(robot)`` is what a message to that robot costs, measured
        (``ramps.core.links``); None: ``net`` for every robot."""
        raise NotImplementedError

    def pools(self, req: PlacementRequest, view: LoadView, now: float, *, net: NetworkEstimate,
              exclude: frozenset[str] = frozenset(), links: Callable[[str], NetworkEstimate] | None = None
              ) -> list[Pool]:
        """What ``req`` would share on each candidate (policies that plan)."""
        raise NotImplementedError


class PaperPolicy(Policy):
    name = "paper"

    def choose(self, req: PlacementRequest, view: LoadView, now: float, rng: random.Random, *, net: NetworkEstimate,
               config: RampsConfig, exclude: frozenset[str] = frozenset(),
               links: Callable[[str], NetworkEstimate] | None = None) -> Placement:
        # the prototype paid the same T_comm for every executor, local included,
        # and slowed its estimate in proportion to the robot's CPU utilisation
        work = req.work
        best_t = math.inf
        best: list[str] = []
        for robot, cores, speed, busy, _, _ in view.scan(now, exclude, paper=True):
            t = work / speed * (1.0 + busy / cores)
            if t < best_t - 1e-9:
                best_t, best = t, [robot]
            elif t <= best_t + 1e-9:
                best.append(robot)
        pick = best[0] if len(best) == 1 else rng.choice(best)
        t = best_t + comm_time(req.payload_size, req.result_size, net)
        return Placement(host=pick, expected_time=t, late=req.deadline is not None and t > req.deadline)


class RampsPolicy(Policy):
    name = "ramps"
    negotiates = True
    shares_load = True
    relocates = True
    plans = True

    def __init__(self) -> None:
        #: a large team's cheapest robots by count at the latest full scan
        #: (``RampsConfig.placement_sample`` of them), the cost of the one
        #: after them, and until when the list stands (``_priced``)
        self._short: list[str] = []
        self._cut = math.inf
        self._short_until = -math.inf

    def _rows(self, req: PlacementRequest, view: LoadView, net: NetworkEstimate,
              scanned: list[tuple[str, float, float, float, float, float]], slots: dict[str, Any],
              links: Callable[[str], NetworkEstimate] | None) -> list[list[Any]]:
        """``choose``'s first estimate on each of the ``scanned`` robots, by
        the count of tasks there: [t, utilisation, robot, runnable,
        background, ramps, cores, speed, weight, t_comm, pool], ``pool`` the
        program's work there and the work left of the programs on the slots
        of its accelerator, where it runs on them there (None on CPUs)."""
        me = view.me
        work = req.work
        payload, result = req.payload_size, req.result_size
        t_comm_default = comm_time(payload, result, net)
        # a ``Links``: its T_comm per robot, kept until that link's figures change
        kept = links.comm_times(payload, result) if isinstance(links, Links) else None
        rows: list[list[Any]] = []
        for robot, cores, speed, ramps, background, weight in scanned:
            runnable = ramps + background
            pool = None
            if robot in slots:  # on its accelerator there: its slots, shared by the programs on them
                _, count, a_speed, on_it, known = slots[robot]
                # the work left where this origin placed them, the new program's work for the others
                others = known + [req.accelerator_work] * (round(on_it) - len(known))
                t = shared_finish_time(req.accelerator_work, others, count, a_speed)
                pool = (req.accelerator_work, others)
                runnable, background, ramps, cores, speed, weight = on_it, 0.0, 0.0, count, a_speed, 1.0
            elif background == 0.0 or weight == 1.0:  # equal sharing (the common, fast case)
                share = cores / (runnable + 1.0)
                t = work / (speed * (share if share < 1.0 else 1.0))  # min(1.0, share), without a call
            else:  # the robot's own busy software outweighs the program
                t = work / (speed * program_share(cores, ramps + 1.0, background, weight))
            t_comm = 0.0
            if robot != me:
                if links is None:
                    t_comm = t_comm_default
                elif kept is None:
                    t_comm = comm_time(payload, result, links(robot))
                else:
                    known = kept.get(robot)
                    if known is None:
                        known = kept[robot] = comm_time(payload, result, links(robot))
                    t_comm = known
                t += t_comm
            rows.append([t, (runnable + 1.0) / cores, robot, runnable, background, ramps, cores, speed, weight,
                         t_comm, pool])
        return rows

    def _priced(self, req: PlacementRequest, view: LoadView, now: float, rng: random.Random, net: NetworkEstimate,
                config: RampsConfig, exclude: frozenset[str], links: Callable[[str], NetworkEstimate] | None
                ) -> list[list[Any]]:
        """``_rows`` of every candidate; in a view of more than
        ``RampsConfig.placement_sample`` robots, of a short list instead
        while it stands: the cheapest robots by count at the latest full
        scan (with this robot and the plan's host), for ``SHORT_LIST_FOR``
        seconds and while one of them still costs no more than the robot
        after them did. A robot off the list gets cheaper only as its
        programs end, which the next full scan sees. Robots that cost the
        same are listed by chance, so origins deciding at once list
        different ones."""
        slots = {row[0]: row for row in view.accelerator_rows(now, req.accelerator, exclude)} \
            if req.accelerator else {}
        sample = config.placement_sample
        if sample and self._short and now < self._short_until:
            names = [n for n in dict.fromkeys([view.me, req.prefer, *self._short]) if n and n not in exclude]
            rows = self._rows(req, view, net, view.scan(now, frozenset(), only=names), slots, links)
            if len(rows) > 1 and min(row[0] for row in rows) <= self._cut:
                return rows
        rows = self._rows(req, view, net, view.scan(now, exclude), slots, links)
        if sample and len(rows) > sample:
            ranked = heapq.nsmallest(sample + 1, rows, key=lambda r: (r[0], rng.random()))
            self._short = [row[2] for row in ranked[:sample]]
            self._cut, self._short_until = ranked[-1][0], now + SHORT_LIST_FOR
        else:
            self._short = []
        return rows

    def pools(self, req: PlacementRequest, view: LoadView, now: float, *, net: NetworkEstimate,
              exclude: frozenset[str] = frozenset(), links: Callable[[str], NetworkEstimate] | None = None
              ) -> list[Pool]:
        """What ``req`` would share on each candidate, as ``choose`` prices
        it: the slots of its accelerator where the robot has that kind, else
        the robot's cores (for a burst's plan, ``ramps.core.burst``)."""
        t_comm = comm_time(req.payload_size, req.result_size, net)
        slots = {row[0]: row for row in view.accelerator_rows(now, req.accelerator, exclude)} \
            if req.accelerator else {}
        out = []
        for robot, cores, speed, ramps, background, weight in view.scan(now, exclude):
            comm = 0.0 if robot == view.me else (
                t_comm if links is None else comm_time(req.payload_size, req.result_size, links(robot)))
            if robot in slots:
                _, count, a_speed, on_it, known = slots[robot]
                out.append(Pool(robot=robot, kind=req.accelerator, cores=count, speed=a_speed, known=tuple(known),
                                unknown=max(0, round(on_it) - len(known)), work=req.accelerator_work, comm=comm))
                continue
            n = round(ramps)
            left = view.remaining_work(robot, now, n, -1.0) if n else []  # -1: one the report does not list
            listed = () if left is None else tuple(x for x in left if x >= 0.0)
            out.append(Pool(robot=robot, kind="", cores=cores, speed=speed, background=background, weight=weight,
                            known=listed, unknown=n - len(listed), work=req.work, comm=comm))
        return out

    def choose(self, req: PlacementRequest, view: LoadView, now: float, rng: random.Random, *, net: NetworkEstimate,
               config: RampsConfig, exclude: frozenset[str] = frozenset(),
               links: Callable[[str], NetworkEstimate] | None = None) -> Placement:
        me = view.me
        work = req.work
        rows = self._priced(req, view, now, rng, net, config, exclude, links)
        # the count above treats every program already on a host as new; on
        # the likeliest hosts, count instead the work they have left (those
        # that end first speed the new one up): T_there under processor sharing
        # (hosts that cost the same by count are drawn at random, so origins
        # deciding at once look at different ones: the power of d choices)
        busy = [r for r in rows if r[5] > 0]
        if len(busy) > REFINE:
            busy = heapq.nsmallest(REFINE, busy, key=lambda r: (r[0], rng.random()))
        pooled = config.place_by == "pool_end" and req.deadline is None and config.energy_weight <= 0
        for row in busy:
            left = view.remaining_work(row[2], now, round(row[5]), work)
            if left is None:
                continue
            t = shared_finish_time(work, left, row[6], row[7], row[4], row[8]) + row[9]
            row[0] = min(row[0], t)
            if pooled:
                row[10] = (work, left, t)
        times = rank_by_energy(view, rows, config.energy_weight)  # energy against time (ramps.core.battery)
        if pooled:  # by the pool's end, then the program's own (RampsConfig.place_by)
            times = _rank_by_pool_end(rows)
            own = {row[2]: t for row, t in zip(rows, times)}
        t_best = min(row[0] for row in rows)
        planned = next((row for row in rows if row[2] == req.prefer), None) if req.prefer else None
        # costs within the tolerance are equal (eq. 1 cannot tell them apart);
        # then the least utilised robot wins, then the one whose load is more
        # ramps programs (they end; busy software does not), then this robot,
        # then chance
        limit = t_best * (1.0 + config.tie_tolerance) + 1e-9
        if req.deadline is not None and t_best <= req.deadline:
            limit = min(limit, req.deadline)  # of equal costs, only those in time
        tied = [row for row in rows if row[0] <= limit]
        if pooled:  # of equal pool ends, the program's own earliest end
            o_best = min(own[row[2]] for row in tied)
            tied = [row for row in tied if own[row[2]] <= o_best * (1.0 + config.tie_tolerance) + 1e-9]
        home = _home(req, rows, me, t_best, config)
        if home is not None and home not in tied:
            tied.append(home)  # a whole core free at home, within HOME_MARGIN: a tie too
        if req.deadline is not None:
            # best fit: of the hosts that meet the deadline with a margin, the
            # slowest, which leaves the faster ones to tighter programs
            fit = [row for row in rows if row[0] * (1.0 + DEADLINE_MARGIN) <= req.deadline]
            if fit:
                t_fit = max(row[0] for row in fit)
                tied = [row for row in fit if row[0] * (1.0 + config.tie_tolerance) >= t_fit - 1e-9]
        u_best = min(row[1] for row in tied)
        tied = [row for row in tied if row[1] <= u_best + 1e-9]
        b_best = min(row[4] for row in tied)
        tied = [row for row in tied if row[4] <= b_best + 1e-9]
        pick = planned or next((row for row in tied if row[2] == me), None)
        if pick is None:
            pick = tied[0] if len(tied) == 1 else rng.choice(tied)
        # the budget: the best other host's cost, as ranked
        alternative = min((row[0] for row in rows if row[2] != pick[2]), default=None) if pooled else None
        unrank(rows, times)
        if not pooled:
            alternative = min((row[0] for row in rows if row[2] != pick[2]), default=None)
        budget = alternative - pick[9] if alternative is not None and math.isfinite(alternative) else None
        if req.deadline is not None and pick[0] <= req.deadline:
            budget = max(budget or 0.0, req.deadline - pick[9])  # what the deadline leaves
        if pick is planned:
            budget = max(budget or 0.0, req.plan_end - pick[9])  # the plan's end: the burst ends no later there
        return Placement(host=pick[2], expected_runnable=pick[3], expected_time=pick[0], time_budget=budget,
                         late=req.deadline is not None and pick[0] > req.deadline)


def _cheapest(n: int, rows: list[list[Any]], rng: random.Random) -> list[list[Any]]:
    """The ``n`` rows of least time (``row[0]``), ties drawn at random: one
    draw per row, in order, and the rows in order of (time, draw, position),
    as ``heapq.nsmallest`` with the key (time, draw) gives them."""
    draw = rng.random
    keyed = [(row[0], draw(), i) for i, row in enumerate(rows)]
    return [rows[k[2]] for k in heapq.nsmallest(n, keyed)]


def _rank_by_pool_end(rows: list[list[Any]]) -> list[float]:
    """Each row's time (``row[0]``, the program's own end there) becomes
    when the last program of its pool would end with the program placed
    there (``pool_finish_time``, plus T_comm), and the own times are returned
    (``unrank`` puts them back). A pool is known by ``row[10]``: the
    program's work there and the work left of the programs on the slots of
    its accelerator, or on the cores where ``choose`` read them (with the
    program's own end there, plus T_comm: the pool's where no program there
    has more work left than it); where it is not, every program there
    counts as the new one's size, and the pool ends with the new program."""
    times = [row[0] for row in rows]
    for row in rows:
        pool = row[10]
        if pool is not None and pool[1]:
            work, left = pool[0], pool[1]
            if len(pool) > 2 and max(left) <= work:  # ``pool_finish_time``'s own case, priced already
                end = pool[2]
            else:
                end = pool_finish_time(work, left, row[6], row[7], row[4], row[8]) + row[9]
            row[0] = max(row[0], end)
    return times


def _home(req: PlacementRequest, rows: list[list[Any]], me: str, t_best: float,
          config: RampsConfig) -> list[Any] | None:
    """This robot's row when it has a whole core (or slot) free for the
    program and ends it within ``HOME_MARGIN`` of ``t_best``; else None.
    Not for a program with a deadline (best fit decides) nor when hosts are
    ranked by energy (``rows`` then hold ranks, not times)."""
    if req.deadline is not None or config.energy_weight > 0:
        return None
    home = next((row for row in rows if row[2] == me), None)
    if home is None or home[3] + 1.0 > home[6] + 1e-9:
        return None
    return home if home[0] <= t_best * (1.0 + HOME_MARGIN) + 1e-9 else None


class RoundRobinPolicy(Policy):
    name = "round_robin"

    def __init__(self) -> None:
        self._next = 0

    def choose(self, req: PlacementRequest, view: LoadView, now: float, rng: random.Random, *, net: NetworkEstimate,
               config: RampsConfig, exclude: frozenset[str] = frozenset(),
               links: Callable[[str], NetworkEstimate] | None = None) -> Placement:
        cands = [row[0] for row in view.scan(now, exclude)]
        ring = [view.me] + sorted(c for c in cands if c != view.me)
        host = ring[self._next % len(ring)]
        self._next += 1
        return Placement(host=host)


class RandomPolicy(Policy):
    name = "random"

    def choose(self, req: PlacementRequest, view: LoadView, now: float, rng: random.Random, *, net: NetworkEstimate,
               config: RampsConfig, exclude: frozenset[str] = frozenset(),
               links: Callable[[str], NetworkEstimate] | None = None) -> Placement:
        cands = sorted(row[0] for row in view.scan(now, exclude))
        return Placement(host=rng.choice(cands))


class LocalOnlyPolicy(Policy):
    name = "local_only"

    def choose(self, req: PlacementRequest, view: LoadView, now: float, rng: random.Random, *, net: NetworkEstimate,
               config: RampsConfig, exclude: frozenset[str] = frozenset(),
               links: Callable[[str], NetworkEstimate] | None = None) -> Placement:
        return Placement(host=view.me)


POLICIES: dict[str, type[Policy]] = {
    p.name: p for p in (RampsPolicy, PaperPolicy, RoundRobinPolicy, RandomPolicy, LocalOnlyPolicy)
}


def make_policy(name: str) -> Policy:
    try:
        return POLICIES[name]()
    except KeyError:
        raise ValueError(f"unknown policy {name!r}; choose one of {', '.join(POLICIES)}") from None
