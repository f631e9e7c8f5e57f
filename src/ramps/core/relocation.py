"""Relocation after placement: when a running program should move, and where.

How this works: every ``relocate_period`` (policies that relocate) the
origin calls ``relocation_check``, which re-evaluates the paper's eq. (1)
for its running programs with what it knows now (fresh reports with the
hosts' work-left estimates, learned work, measured links). Its estimate of
how far a program is comes from the program's own progress when it reports
any, and from processor sharing at its host's reported load otherwise. A
program moves when its remaining time where it runs exceeds the time to
finish on the best other robot (from scratch, or from its last checkpoint,
plus T_comm of parameters and checkpoint) by ``relocate_gain`` and
``relocate_min_gain`` together (``worth_moving``), or, placing by the pool's
end (``RampsConfig.place_by`` "pool_end") where programs share its host's
cores, when the last program of its host's pool would end that much sooner
without it than the later of the pool without it and the target's pool with
it (a move for the programs it leaves, not for itself), and has for
``relocate_persist`` seconds (a brief spike of load moves nothing); at most
``relocate_max_moves`` times (a move the new host refuses as "late", to
keep a deadline it runs, counts none), never within ``relocate_settle`` of an
acceptance, at most one program off a host per check. ``price_move`` asks
the program's policy for the best other host with a generator of the
origin's own for relocation, so turning relocation on leaves every
placement's draws unchanged. A move found worth it is the ``relocate``
event of the program's state machine; the move itself (``MOVING``, the old
copy running until the new host accepts) is ``ramps.core.moves``.

Calm (issue 23: corrections of robots' speeds swung 0.56-1.87x within
minutes and moves followed them, back and forth, restarting programs from
zero). On top of the thresholds:

- **never back**: a program never moves to a robot it already ran on
  (``AutonomousProgram.ran_on``), so it cannot go back and forth;
- **the work a restart loses**: a program without a checkpoint is priced
  from scratch there (T_there is its whole work, so what it did here is
  lost in the price), and it never moves once an *upper* estimate of what
  it has done (``done_bound``: its time there, the origin's own stalls
  included, at one whole core of the host's faster speed, reported or
  corrected, or its own progress if further) passes ``relocate_max_done``
  (half) of its work. The price itself keeps the processor-sharing
  estimate: priced with the bound, the campaign comparison's median went
  from 0.835 to 0.913 (the bound counts a whole core on a loaded host);
- **no move on an uncertain estimate** (``uncertain``, counted by reason in
  ``Origin.withheld``): within ``relocate_calm`` of this origin's own stall
  (its view and clock were behind), or of a change of the host's or the
  target's speed correction (``Origin.factor_seen``, read from the view); a
  host or target whose latest report is older than ``relocate_stale``; a
  program whose learned work is scattered (its latest runs more than
  ``relocate_max_spread`` apart per declared unit). The gain must then last
  ``relocate_persist`` again once the doubt is gone.

Fleets: in a view of more robots than ``placement_sample`` a check looks
only at the running programs that can still move: a program whose
``done_bound`` passed ``relocate_max_done`` (no checkpoint) is marked
``settled`` for its attempt and passed over from then on, programs within
``relocate_settle`` of their acceptance need no scan of the view, and once
none is left the checks stop until the next acceptance. A check then costs
the programs placed in the last half a program's run, not all of them.
Smaller teams check every running program every period.

Rules: functions of the origin they decide for, which they see as a
``RelocatingOrigin`` (what ``ramps.core.origin.Origin`` offers them: its
view, programs and figures, the policy of each program, and ``relocate``, the
one thing they do to it, which steps a program through its table); no clock,
no I/O.
"""

from __future__ import annotations

import math
import random
from collections.abc import Sequence
from typing import Protocol

import msgspec

from ramps.core.config import RampsConfig
from ramps.core.cost import NetworkEstimate, pool_finish_time, program_share, shared_finish_time
from ramps.core.events import Action, Submit
from ramps.core.links import Links
from ramps.core.loadview import LoadView
from ramps.core.policy import Placement, PlacementRequest, Policy
from ramps.core.program import AutonomousProgram, ProgramState
from ramps.core.relink import Relink

S = ProgramState
#: most running programs one relocation check prices against the team (the
#: longest remaining first), so a check stays cheap with thousands running
RELOCATE_BATCH = 8


class RelocatingOrigin(Protocol):
    """The origin as relocation sees it (``ramps.core.origin.Origin`` is one)."""

    me: str
    view: LoadView
    config: RampsConfig
    net: NetworkEstimate
    links: Links | None
    relink: Relink
    programs: dict[str, AutonomousProgram]
    #: relocation's own generator (placements' draws stay as they were)
    relocation_rng: random.Random
    #: this robot's latest wake from a stall, and its stalls' seconds in all
    woke_at: float
    stalled_s: float
    #: host -> (its speed correction as relocation last saw it, since when)
    factor_seen: dict[str, tuple[float, float]]
    #: moves withheld on an uncertain estimate, by reason
    withheld: dict[str, int]

    def work_estimate(self, sub: Submit) -> float: ...

    def accelerator_work_estimate(self, sub: Submit) -> float: ...

    def policy_for(self, sub: Submit) -> Policy: ...

    def learned_runs(self, program: str) -> Sequence[float]: ...

    def relocate(self, ap: AutonomousProgram, placement: Placement, now: float, out: list[Action]) -> None: ...


def relocation_check(origin: RelocatingOrigin, now: float, out: list[Action]) -> bool:
    """Re-evaluate eq. (1) for ``origin``'s running programs (see the module
    docstring). Returns whether any program may still move later."""
    cfg = origin.config
    programs = to_check(origin, now)
    if isinstance(programs, bool):
        return programs
    # the rows, and the fastest a new program could run anywhere by the count of tasks (the policy's
    # first estimate): a program that would not gain by the thresholds even at that rate is not
    # priced (most checks in a balanced team end here, at O(programs))
    rows, best_rate = origin.view.rows_and_best_rate(now)
    keep = False
    see_factors(origin, now)
    stalled = now - origin.woke_at < cfg.relocate_calm  # this robot's view and clock were behind
    if best_rate <= 0.0:
        return any(ap.state is S.RUNNING or ap.state is S.MOVING for ap in programs)
    priced: list[tuple[float, float, float, AutonomousProgram]] = []
    # what the loop reads of each host (and program) once: nothing it does changes them
    shares: dict[str, float] = {}
    ages: dict[str, float | None] = {}
    doubts: dict[tuple[str, str], str | None] = {}
    tops: dict[str, tuple[float, int]] = {}
    floors: dict[tuple[str, float], float] = {}
    for ap in programs:
        if ap.state is not S.RUNNING and ap.state is not S.MOVING:
            continue
        if not origin.policy_for(ap.submit).relocates or ap.submit.local_only or ap.moves >= cfg.relocate_max_moves:
            continue
        if ap.accelerator:
            continue  # its host's CPU figures say nothing of a program on its accelerator: it stays
        keep = True
        row = rows.get(ap.host or "")
        if row is None:
            continue  # its host is suspect or gone quiet: failure detection's business
        host, cores, speed, ramps, background, weight = row
        share = shares.get(host)  # one figure for every program on this host
        if share is None:
            share = shares[host] = program_share(cores, max(1.0, ramps), background, weight)
        ap.done = min(ap.work, ap.done + max(0.0, now - ap.done_at) * speed * share)
        ap.done_at = now
        if ap.state is not S.RUNNING or len(ap.live) != 1 or now - ap.accepted_at < cfg.relocate_settle:
            continue
        placed = ap.placed_host
        age = ages[placed] if placed in ages else ages.setdefault(placed, origin.view.report_age(placed, now))
        if ap.host != origin.me and (age is None or now - age < ap.accepted_at):
            continue  # no report of its host since it started there
        if ap.checkpoint is None and done_bound(origin, ap, now, speed) > cfg.relocate_max_done * ap.work:
            ap.move_wanted_since = None
            ap.settled = ap.attempt  # passed over from now on in a large view
            continue  # a restart would lose what it did, and it may have done over half its work
        doubt = "stalled" if stalled else doubt_of(origin, ap, now, doubts)
        if doubt is not None:
            origin.withheld[doubt] = origin.withheld.get(doubt, 0) + 1
            ap.move_wanted_since = None
            continue
        left = max(0.0, ap.work - ap.done)
        t_floor = floor_kept(origin, ap, now, best_rate, floors)
        # a host whose programs share its cores: a move frees some for the rest (``host_times``)
        crowded = share < 1.0 and cfg.place_by == "pool_end"
        if not worth_moving(origin, pool_bound(origin, ap, row, left, share, tops) if crowded
                            else left / (speed * share), t_floor):
            ap.move_wanted_since = None
            continue  # not even by the count of tasks here (an upper bound of the estimates below)
        t_here, stay, freed = host_times(origin, ap, now, row, left, t_floor)
        if not (worth_moving(origin, t_here, t_floor) or worth_moving(origin, stay, max(freed, t_floor))):
            ap.move_wanted_since = None
        elif ap.move_wanted_since is None:
            ap.move_wanted_since = now  # a load spike must last before a program moves for it
        if ap.move_wanted_since is not None and now - ap.move_wanted_since >= cfg.relocate_persist:
            priced.append((t_here, stay, freed, ap))
    priced.sort(key=lambda x: -x[0])
    moved_off: set[str] = set()
    for t_here, stay, freed, ap in priced[:RELOCATE_BATCH]:
        if ap.host in moved_off:
            continue  # one at a time off a host: the next check sees it lighter
        placement = price_move(origin, ap, t_here, now, stay, freed)
        if placement is not None:
            moved_off.add(ap.host or "")
            origin.relocate(ap, placement, now, out)
    return keep


def floor_of(origin: RelocatingOrigin, ap: AutonomousProgram, now: float, best_rate: float) -> float:
    """The fastest ``ap`` could end anywhere: its learned work, from its
    checkpoint, at ``best_rate`` (the team's best CPU rate by the count of
    tasks), or on a slot (``slot_floor``) where it can use an accelerator."""
    t_floor = origin.work_estimate(ap.submit) * (
        1.0 - (ap.checkpoint_fraction if ap.checkpoint is not None else 0.0)) / best_rate
    if ap.submit.accelerator:  # on a CPU, but it can use an accelerator: the fastest slot may be its floor
        t_floor = min(t_floor, slot_floor(origin, ap, now))
    return t_floor


def floor_kept(origin: RelocatingOrigin, ap: AutonomousProgram, now: float, best_rate: float,
               floors: dict[tuple[str, float], float]) -> float:
    """``floor_of``, kept in ``floors`` for the rest of a check: the same for
    every program of one name and declared work without a checkpoint or an
    accelerator (its learned work, at ``best_rate``)."""
    sub = ap.submit
    if ap.checkpoint is not None or sub.accelerator:
        return floor_of(origin, ap, now, best_rate)
    key = (sub.program, sub.work)
    t = floors.get(key)
    if t is None:
        t = floors[key] = floor_of(origin, ap, now, best_rate)
    return t


def slot_floor(origin: RelocatingOrigin, ap: AutonomousProgram, now: float) -> float:
    """The fastest ``ap`` (running on a CPU) could end on a slot of its kind of
    accelerator elsewhere, as its policy sees the slots (``Policy.pools``):
    its learned accelerator work, from its checkpoint, alone on the fastest
    slot (inf where there is none, or the policy prices no slots). Without it
    a program that its declaration kept off a slot, and that its runs since
    show faster there, is priced by CPUs only and never moves there."""
    sub = ap.submit
    part = 1.0 - (ap.checkpoint_fraction if ap.checkpoint is not None else 0.0)
    req = PlacementRequest(program_id=ap.program_id, work=origin.work_estimate(sub) * part,
                           payload_size=sub.payload_size, result_size=sub.result_size, accelerator=sub.accelerator,
                           accelerator_work=origin.accelerator_work_estimate(sub) * part)
    try:
        pools = origin.policy_for(sub).pools(req, origin.view, now, net=origin.net,
                                             exclude=frozenset({ap.host or ""}))
    except NotImplementedError:
        return math.inf
    return min((p.work / p.speed for p in pools if p.kind), default=math.inf)


def host_times(origin: RelocatingOrigin, ap: AutonomousProgram, now: float,
               row: tuple[str, float, float, float, float, float], left: float,
               floor: float | None = None) -> tuple[float, float, float]:
    """When ``ap``, with ``left`` units to do, ends where it runs (its host's
    ``row``: processor sharing with the work its host's report lists left),
    and, under ``RampsConfig.place_by`` "pool_end", when the last program of
    its host's pool ends with it there and without it (else its own end
    for both). With ``floor`` (the soonest it could end anywhere), the end
    without it is inf where neither end with it beats ``floor`` by the
    thresholds (``worth_moving``, which a later floor passes no sooner):
    no move is wanted then, whatever that end."""
    _, cores, speed, ramps, background, weight = row
    others = origin.view.remaining_work(ap.placed_host, now, round(ramps), ap.work) or []
    if others:  # one of them is this program: the one closest to its estimate (the first of equals)
        gaps = [abs(x - left) for x in others]
        others.pop(gaps.index(min(gaps)))
    own = shared_finish_time(left, others, cores, speed, background, weight)
    if origin.config.place_by != "pool_end" or not others:
        return own, own, own
    top = max(others)
    rest = list(others)
    rest.remove(top)
    stay = own  # ``pool_finish_time``: its own end is the pool's
    if top > left:  # ``pool_finish_time`` of the pool with it, its list built once
        rest.append(left)
        stay = shared_finish_time(top, rest, cores, speed, background, weight)
        rest.pop()
    if (floor is not None and floor == floor and 1.0 + origin.config.relocate_gain >= 0.0
            and not worth_moving(origin, own, floor) and not worth_moving(origin, stay, floor)):
        return own, stay, math.inf
    return own, stay, shared_finish_time(top, rest, cores, speed, background, weight)


def pool_bound(origin: RelocatingOrigin, ap: AutonomousProgram, row: tuple[str, float, float, float, float, float],
               left: float, share: float, tops: dict[str, tuple[float, int]]) -> float:
    """An upper bound of both ends ``host_times`` gives for ``ap`` (``left``
    units to do, its host's ``row`` and ``share``), without the host's work
    list: every program of the pool runs at least at the share of them all
    (``program_share`` only falls as programs are added), so none ends later
    than the pool's largest work left at that share. The largest is ``ap``'s,
    its host's largest listed (``LoadReport.remaining``, which only ages down)
    or, where the view counts programs the report does not list, ``ap.work``
    (``LoadView.remaining_work``'s guess for them). ``tops`` keeps each host's
    largest listed and their count for the rest of a check. A count of
    programs that is not whole gets no bound (inf)."""
    host, _, speed, ramps, _, _ = row
    programs = max(1, round(ramps))
    if programs != max(1.0, ramps):
        return math.inf
    top = tops.get(host)
    if top is None:
        rep = origin.view.report_of(host)
        listed = rep.remaining if rep is not None else []
        top = tops[host] = (max(max(listed, default=0.0), 0.0), len(listed))
    most = max(left, top[0], ap.work) if programs > top[1] else max(left, top[0])
    return most / (speed * share) * (1.0 + 1e-9)


def doubt_of(origin: RelocatingOrigin, ap: AutonomousProgram, now: float,
             doubts: dict[tuple[str, str], str | None]) -> str | None:
    """``uncertain``, kept in ``doubts`` for the rest of a check: the same for
    every program of one name on one host."""
    key = (ap.placed_host, ap.submit.program)
    return doubts[key] if key in doubts else doubts.setdefault(key, uncertain(origin, ap, now))


def to_check(origin: RelocatingOrigin, now: float) -> list[AutonomousProgram] | bool:
    """The programs a check looks at: all of them, or in a fleet (a view of
    more than ``placement_sample`` robots) the running ones not ``settled``;
    a bool where a fleet's check has nothing to do: whether to check again."""
    cfg = origin.config
    if not 0 < cfg.placement_sample < origin.view.size():
        return list(origin.programs.values())
    programs = [ap for ap in origin.programs.values()
                if (ap.state is S.RUNNING or ap.state is S.MOVING) and ap.settled != ap.attempt]
    if not programs:
        return False  # the next acceptance starts the checks again
    if all(ap.state is S.RUNNING and now - ap.accepted_at < cfg.relocate_settle for ap in programs):
        return True  # none may move yet: no need to read the view
    return programs


def price_move(origin: RelocatingOrigin, ap: AutonomousProgram, t_here: float, now: float,
               stay: float | None = None, freed: float | None = None) -> Placement | None:
    """Where ``ap`` would finish sooner by the relocation thresholds, or None:
    its own end there against ``t_here``, or, for a CPU program, the later of
    its host's pool without it (``freed``) and the target's pool with it
    against its host's pool with it (``stay``)."""
    sub = ap.submit
    work = origin.work_estimate(sub) * (1.0 - (ap.checkpoint_fraction if ap.checkpoint is not None else 0.0))
    # never back where it ran, nor onto a robot whose figures are in doubt
    never = frozenset({ap.host or ""}) | frozenset(ap.ran_on) | unsettled(origin, now) | origin.view.low_battery
    placement = origin.policy_for(sub).choose(
        PlacementRequest(program_id=ap.program_id, work=work,
                         payload_size=sub.payload_size + len(ap.checkpoint or b""), result_size=sub.result_size,
                         accelerator=sub.accelerator, accelerator_work=origin.accelerator_work_estimate(sub) * (
                             1.0 - (ap.checkpoint_fraction if ap.checkpoint is not None else 0.0))),
        origin.view, now, origin.relocation_rng, net=origin.net, config=origin.config,
        exclude=never | origin.view.short_of_memory(sub.memory) | origin.relink.excluded(origin.view.robots(), now),
        links=origin.links,
    )
    t_there = placement.expected_time
    # (a view that has only those robots left ignores the exclusion: nothing moves then)
    if placement.host in never or t_there is None:
        return None
    cfg = origin.config
    # the new host takes it if it finishes there within what staying costs
    # (less the thresholds), whatever the origin's view missed
    if worth_moving(origin, t_here, t_there):
        budget = t_here / (1.0 + cfg.relocate_gain)
    elif stay is not None and freed is not None and not sub.accelerator \
            and worth_moving(origin, stay, max(freed, t_there, pool_there(origin, placement.host, work, now))):
        budget = stay / (1.0 + cfg.relocate_gain)
    else:
        return None
    if placement.time_budget is not None:
        budget = min(budget, placement.time_budget)
    return msgspec.structs.replace(placement, time_budget=budget)


def pool_there(origin: RelocatingOrigin, host: str, work: float, now: float) -> float:
    """When the last program of ``host``'s pool would end with one of
    ``work`` units more there (its report's work left, processor sharing)."""
    row = origin.view.rows_and_best_rate(now)[0].get(host)
    if row is None:
        return math.inf
    _, cores, speed, ramps, background, weight = row
    others = origin.view.remaining_work(host, now, round(ramps), work) or []
    return pool_finish_time(work, others, cores, speed, background, weight)


def worth_moving(origin: RelocatingOrigin, t_here: float, t_there: float) -> bool:
    """Eq. (1) with hysteresis: the relative AND the absolute gain."""
    cfg = origin.config
    return t_here > t_there * (1.0 + cfg.relocate_gain) and t_here - t_there > cfg.relocate_min_gain


def done_bound(origin: RelocatingOrigin, ap: AutonomousProgram, now: float, speed: float) -> float:
    """The most work ``ap``'s current attempt can have done: its time since
    it was offered (the origin's stalls, taken out of its clock, put back)
    at one whole core of its host's speed, corrected or as it reports it,
    whichever is faster; its own progress or the estimate if further."""
    host = ap.placed_host
    rep = origin.view.report_of(host)
    reported = origin.view.speed if host == origin.me or rep is None else rep.speed
    elapsed = max(0.0, now - ap.placed_at) + max(0.0, origin.stalled_s - ap.stall_base)
    return min(ap.work, max(ap.done, elapsed * max(speed, reported)))


def see_factors(origin: RelocatingOrigin, now: float) -> None:
    """Note when each host's speed correction changed (read from the view;
    one first seen away from 1 counts as changed now)."""
    for host, factor in origin.view.speed_factor.items():
        seen = origin.factor_seen.get(host)
        if seen is None or seen[0] != factor:
            origin.factor_seen[host] = (factor, now if seen is not None or factor != 1.0 else -math.inf)


def factor_settled(origin: RelocatingOrigin, robot: str, now: float) -> bool:
    seen = origin.factor_seen.get(robot)
    return seen is None or now - seen[1] >= origin.config.relocate_calm


def uncertain(origin: RelocatingOrigin, ap: AutonomousProgram, now: float) -> str | None:
    """Why the estimate of moving ``ap`` is too uncertain to act on now, or None."""
    cfg = origin.config
    host = ap.placed_host
    if not factor_settled(origin, host, now):
        return "host speed changed"
    age = origin.view.report_age(host, now)
    if host != origin.me and (age is None or age > cfg.relocate_stale):
        return "host report stale"
    runs = origin.learned_runs(ap.submit.program)
    if runs and len(runs) >= 2 and max(runs) > cfg.relocate_max_spread * min(runs):
        return "work scattered"
    return None


def unsettled(origin: RelocatingOrigin, now: float) -> frozenset[str]:
    """Robots no program moves to now: their speed correction changed within
    ``relocate_calm``, or their latest report is older than ``relocate_stale``."""
    cfg = origin.config
    view, me, calm = origin.view, origin.me, cfg.relocate_calm
    out = set(view.stale(now, cfg.relocate_stale))
    out.update(robot for robot, (_, since) in origin.factor_seen.items()
               if not now - since >= calm and robot != me and view.holds(robot))  # not ``factor_settled``
    return frozenset(out)
