"""Several origins at once: generated scenarios against the best achievable.

How this works: ``generate(family, count, seed)`` builds random but
reproducible scenarios of one family: a team of 3-20 robots (identical and
idle, some running busy processes, or of mixed cores and speeds), 2 to all of
them submitting identical programs, either in one burst (every origin
re-plans at the same moment, as after a shared event) or staggered (origins
start within a few seconds of each other). Each scenario is simulated with
the chosen policy and round robin on several seeds, and its makespan is
compared with two references computed under the same processor-sharing
model (``ramps.experiments.metrics``):

* ``lower_bound``: no schedule can do better. Programs released at or after
  time r cannot all finish before r plus the best makespan of those
  programs started together on an idle team, for every release time r.
* ``oracle``: a feasible schedule made by a central scheduler that knows
  every robot's exact state at every instant and places each program, when
  it is released, where the robot's finish time grows least. No real team
  can know that much, so it is a strong reference; it is not always optimal
  either. The exact optimum lies between the two: when they are equal (every
  burst scenario here is within 0.1%), the ratio to the lower bound is the
  ratio to the optimum; otherwise it overstates it.
* the exact optimum, where the two differ: ``ramps.experiments.optimum.solve``
  improves the oracle's schedule, raises the bound, and searches, within a
  time limit per scenario. A scenario it does not prove keeps an interval:
  the optimum lies between its best bound and its best schedule.

Programs within a burst are submitted 0.05 s apart (each autonomous program
is started by the application in turn), as in the paper's experiments.
"""

from __future__ import annotations

import math
import random
import statistics
from typing import Callable, Sequence

import msgspec

from ramps.core.config import RampsConfig
from ramps.experiments.metrics import Machine, rate
from ramps.experiments.optimum import solve
from ramps.experiments.optimum_bounds import simple_bound
from ramps.experiments.optimum_online import online_bound, online_limit
from ramps.sim.engine import simulate
from ramps.sim.scenario import ProgramSpec, RobotSpec, Scenario

TEAMS = ("idle", "loaded", "mixed")
TIMINGS = ("burst", "staggered")
#: family name -> (team kind, timing); "multi-origin" runs all six
FAMILIES: dict[str, list[tuple[str, str]]] = {f"{t}-{s}": [(t, s)] for t in TEAMS for s in TIMINGS}
FAMILIES["multi-origin"] = [(t, s) for t in TEAMS for s in TIMINGS]
WORK = 53.0
SPACING = 0.05


class SweepRun(msgspec.Struct, kw_only=True):
    seed: int
    makespan: float
    round_robin: float
    completed: int
    lost: int
    duplicated: int
    distribution: list[int]


class SweepScenario(msgspec.Struct, kw_only=True):
    name: str
    team: str
    timing: str
    robots: int
    origins: int
    programs: int
    lower_bound: float
    oracle: float
    oracle_distribution: list[int]
    runs: list[SweepRun]
    #: median over seeds, divided by the lower bound / the oracle
    ratio_lower_bound: float
    ratio_oracle: float
    ratio_round_robin: float
    #: the exact optimum where it is known: the lower bound when the oracle
    #: reaches it, else what ``ramps.experiments.optimum`` proved (None: open)
    optimum: float | None = None
    ratio_optimum: float | None = None
    #: where the optimum is open, it lies in [best_bound, best_schedule]: the
    #: strongest lower bound and the best schedule found (both the optimum
    #: when it is known; None when no search ran)
    best_bound: float | None = None
    best_schedule: float | None = None
    #: the policy's median makespan over best_bound: at least its ratio to
    #: the optimum (equal when it is proven)
    ratio_best_bound: float | None = None
    search_seconds: float = 0.0
    #: where the policy is more than ``ONLINE_ABOVE`` above the best bound and
    #: --online-seconds asks: no placement that decides each program at its
    #: release is within this ratio of the optimum on the scenario and all its
    #: prefixes (``ramps.experiments.optimum_online.online_bound``; 1.0: nothing shown)
    online_ratio: float | None = None


class FamilyRow(msgspec.Struct, kw_only=True):
    family: str
    scenarios: int
    runs: int
    median_ratio: float
    p90_ratio: float
    worst_ratio: float
    median_ratio_oracle: float
    worst_ratio_oracle: float
    median_round_robin_ratio: float
    worst_round_robin_ratio: float
    within_2pct: int
    within_5pct: int
    lost: int
    duplicated: int
    #: scenarios whose exact optimum is known, and the ratios to it there
    proven: int = 0
    median_ratio_optimum: float | None = None
    worst_ratio_optimum: float | None = None
    #: every scenario the search covered: the ratio to the optimum, or an
    #: upper limit on it (the ratio to the best bound) where it is open
    searched: int = 0
    median_ratio_best_bound: float | None = None
    worst_ratio_best_bound: float | None = None
    #: the widest open interval (best schedule / best bound - 1), 0 if none
    worst_gap: float = 0.0
    #: scenarios more than 5% above the best bound, and of those the ones where no
    #: online placement can be within 5% (online_ratio > 1.05)
    above_5pct: int = 0
    online_impossible: int = 0


class SweepReport(msgspec.Struct, kw_only=True):
    family: str
    policy: str
    #: settings that differ from the defaults
    settings: dict[str, object]
    seed: int
    seeds_per_scenario: int
    families: list[FamilyRow]
    scenarios: list[SweepScenario]
    wall_seconds: float = 0.0


# ---------------------------------------------------------------- scenarios
def generate(team_kind: str, timing: str, index: int, seed: int) -> Scenario:
    """One reproducible scenario of a family."""
    rng = random.Random(f"{seed}/{team_kind}/{timing}/{index}")
    n = rng.randint(3, 20)
    robots = []
    for i in range(1, n + 1):
        cores, speed, background = 4, 1.0, 0
        if team_kind == "loaded" and rng.random() < 0.4:
            background = rng.choice((2, 4, 8))
        elif team_kind == "mixed":
            cores = rng.choice((2, 4, 4, 8))
            speed = rng.choice((0.5, 1.0, 1.0, 1.5, 2.0))
            if rng.random() < 0.2:
                background = rng.choice((2, 4))
        robots.append(RobotSpec(name=f"r{i}", cores=cores, speed=speed, background=background))
    if team_kind == "loaded" and all(r.background == 0 for r in robots):
        robots[-1] = msgspec.structs.replace(robots[-1], background=8)
    k = rng.randint(2, n)
    origins = rng.sample([r.name for r in robots], k)
    total_cores = sum(r.cores for r in robots)
    total = max(k, round(total_cores * rng.uniform(0.5, 3.0)))
    shares = [rng.uniform(0.5, 1.5) for _ in origins]
    counts = [max(1, round(total * s / sum(shares))) for s in shares]
    programs = []
    for origin, count in zip(origins, counts):
        at = rng.uniform(0.0, 0.1) if timing == "burst" else rng.uniform(0.0, 10.0)
        programs.append(ProgramSpec(origin=origin, count=count, work=WORK, at=at, spacing=SPACING))
    return Scenario(name=f"{team_kind}-{timing}-{index}", seed=rng.getrandbits(32), robots=robots,
                    programs=programs)


def releases(sc: Scenario) -> list[float]:
    """Submit times of every program, from the first one (no jitter here)."""
    times = sorted(p.at + i * p.spacing for p in sc.programs for i in range(p.count))
    return [t - times[0] for t in times]


def machines(sc: Scenario) -> list[Machine]:
    return [Machine(r.cores, r.speed, r.background) for r in sc.team()]


def lower_bound(sc: Scenario, work: float = WORK) -> float:
    """No schedule finishes before this (see the module docstring)."""
    return simple_bound(machines(sc), releases(sc), work)


class _PS:
    """One robot under processor sharing: every program runs at the same rate."""

    __slots__ = ("m", "left", "t")

    def __init__(self, m: Machine) -> None:
        self.m = m
        self.left: list[float] = []
        self.t = 0.0

    def rate(self, k: int) -> float:
        return rate(self.m, k)

    def advance(self, to: float) -> None:
        while self.left and self.t < to:
            r = self.rate(len(self.left))
            first = min(self.left)
            dt = first / r
            if self.t + dt > to:
                done = (to - self.t) * r
                self.left = [x - done for x in self.left]
                break
            self.t += dt
            self.left = [x - first for x in self.left if x - first > 1e-9]
        self.t = to

    def finish_with(self, extra: float | None) -> float:
        left = sorted(self.left + ([extra] if extra is not None else []))
        t, done = self.t, 0.0
        for i, x in enumerate(left):
            t += (x - done) / self.rate(len(left) - i)
            done = x
        return t


def oracle(sc: Scenario, work: float = WORK) -> tuple[float, list[int]]:
    """Makespan and distribution of the omniscient central greedy schedule."""
    end, placed = oracle_schedule(sc, work)
    counts = [0] * len(sc.team())
    for i in placed:
        counts[i] += 1
    return end, counts


def oracle_schedule(sc: Scenario, work: float = WORK) -> tuple[float, list[int]]:
    """The oracle's makespan and the robot of each program, in ``releases`` order."""
    team = [_PS(m) for m in machines(sc)]
    placed = []
    end = 0.0
    for r in releases(sc):
        for ps in team:
            ps.advance(r)
        best = min(range(len(team)), key=lambda i: (team[i].finish_with(work), -team[i].m.cores * team[i].m.speed))
        team[best].left.append(work)
        placed.append(best)
    for ps in team:
        end = max(end, ps.finish_with(None))
    return end, placed


# ---------------------------------------------------------------- running
#: a scenario this far above its best bound gets ``online_bound`` (with --online-seconds),
#: and ``online_limit`` too when it has at most this many programs
ONLINE_ABOVE = 1.05
ONLINE_EXACT_PROGRAMS = 12


def run_scenario(sc: Scenario, *, policy: str, seeds: int, seed: int, exact_nodes: int = 0,
                 exact_seconds: float = 0.0, online_seconds: float = 0.0) -> SweepScenario:
    """``exact_seconds`` > 0 or ``exact_nodes`` > 0 searches for the exact
    optimum where the lower bound and the oracle differ, for at most that
    long or that many placements (both when both are given)."""
    names = [r.name for r in sc.team()]
    runs = []
    for s in range(seeds):
        run_seed = seed * 1_000_003 + s
        res = simulate(sc, policy=policy, seed=run_seed)
        rr = simulate(sc, policy="round_robin", seed=run_seed)
        runs.append(SweepRun(seed=run_seed, makespan=res.makespan, round_robin=rr.makespan,
                             completed=res.completed, lost=res.lost, duplicated=res.duplicated,
                             distribution=[res.distribution.get(n, 0) for n in names]))
    lb = lower_bound(sc)
    team, rel = machines(sc), releases(sc)
    orc, placed = oracle_schedule(sc)  # once: the search and the online bound start from it too
    orc_dist = [placed.count(i) for i in range(len(names))]
    med = statistics.median(r.makespan for r in runs)
    optimum: float | None = None
    bound = schedule = None
    seconds = 0.0
    if orc <= lb * (1 + 1e-9):
        optimum = bound = schedule = lb  # a schedule reaches the bound: it is the optimum
    elif exact_nodes > 0 or exact_seconds > 0:
        found = solve(team, rel, WORK, placed,
                      time_limit=exact_seconds if exact_seconds > 0 else math.inf,
                      max_nodes=exact_nodes if exact_nodes > 0 else 10**12)
        optimum = found.best if found.proven else None
        bound, schedule, seconds = max(lb, found.bound), found.best, found.seconds
    online = None
    if online_seconds > 0 and bound is not None and med > ONLINE_ABOVE * bound:
        # the annealing of the prefixes' schedules decides how much it shows: more steps with more time
        online = online_bound(team, rel, WORK, placed, upper=schedule,
                              time_limit=online_seconds, steps=max(100_000, int(2_000 * online_seconds))).ratio
        if len(rel) <= ONLINE_EXACT_PROGRAMS:  # small: the exhaustive limit, which is exact
            exact = online_limit(team, rel, WORK, max_nodes=200_000)
            if exact is not None:
                online = max(online, exact.ratio)
    return SweepScenario(
        name=sc.name, team=sc.name.split("-")[0], timing=sc.name.split("-")[1], robots=len(names),
        origins=len(sc.programs), programs=sum(p.count for p in sc.programs), lower_bound=lb, oracle=orc,
        oracle_distribution=orc_dist, runs=runs, ratio_lower_bound=med / lb, ratio_oracle=med / orc,
        ratio_round_robin=statistics.median(r.round_robin for r in runs) / lb,
        optimum=optimum, ratio_optimum=None if optimum is None else med / optimum,
        best_bound=bound, best_schedule=schedule, ratio_best_bound=None if bound is None else med / bound,
        search_seconds=seconds, online_ratio=online,
    )


def _row(name: str, scs: Sequence[SweepScenario]) -> FamilyRow:
    ratios = sorted(s.ratio_lower_bound for s in scs)
    orc = [s.ratio_oracle for s in scs]
    rr = [s.ratio_round_robin for s in scs]
    opt = [s.ratio_optimum for s in scs if s.ratio_optimum is not None]
    upto = [s.ratio_best_bound for s in scs if s.ratio_best_bound is not None]
    gaps = [s.best_schedule / s.best_bound - 1 for s in scs
            if s.optimum is None and s.best_bound is not None and s.best_schedule is not None]
    return FamilyRow(
        family=name, scenarios=len(scs), runs=sum(len(s.runs) for s in scs),
        median_ratio=statistics.median(ratios), p90_ratio=ratios[min(len(ratios) - 1, math.ceil(0.9 * len(ratios)) - 1)],
        worst_ratio=ratios[-1], median_ratio_oracle=statistics.median(orc), worst_ratio_oracle=max(orc),
        median_round_robin_ratio=statistics.median(rr), worst_round_robin_ratio=max(rr),
        within_2pct=sum(1 for x in ratios if x <= 1.02), within_5pct=sum(1 for x in ratios if x <= 1.05),
        lost=sum(r.lost for s in scs for r in s.runs), duplicated=sum(r.duplicated for s in scs for r in s.runs),
        proven=len(opt), median_ratio_optimum=statistics.median(opt) if opt else None,
        worst_ratio_optimum=max(opt) if opt else None, searched=len(upto),
        median_ratio_best_bound=statistics.median(upto) if upto else None,
        worst_ratio_best_bound=max(upto) if upto else None, worst_gap=max(gaps, default=0.0),
        above_5pct=sum(1 for x in upto if x > ONLINE_ABOVE),
        online_impossible=sum(1 for s in scs if s.ratio_best_bound is not None and s.ratio_best_bound > ONLINE_ABOVE
                              and s.online_ratio is not None and s.online_ratio > ONLINE_ABOVE),
    )


def run_sweep(family: str = "multi-origin", *, per_family: int = 36, seeds: int = 3, seed: int = 0,
              policy: str = "ramps", config: RampsConfig | None = None,
              progress: Callable[[int, int], None] | None = None, exact_nodes: int = 0,
              exact_seconds: float = 0.0, online_seconds: float = 0.0,
              only: Sequence[str] = ()) -> SweepReport:
    """``config`` replaces the default settings in every scenario (to measure
    what one mechanism is worth, e.g. ``RampsConfig(prompt_reports=False)``).
    ``only``: run just the scenarios of these names (e.g. ``mixed-staggered-1``)."""
    if family not in FAMILIES:
        raise ValueError(f"unknown family {family!r}; choose one of {', '.join(FAMILIES)}")
    import time as _wallclock

    started = _wallclock.perf_counter()
    kinds = FAMILIES[family]
    wanted = set(only)
    names = {f"{t}-{s}-{i}" for t, s in kinds for i in range(per_family)}
    if wanted - names:
        raise ValueError(f"no scenario {', '.join(sorted(wanted - names))} in {family} with {per_family} per family "
                         "(names are TEAM-TIMING-INDEX, e.g. mixed-staggered-1)")
    total = len(wanted) if wanted else len(kinds) * per_family
    scenarios: list[SweepScenario] = []
    rows: list[FamilyRow] = []
    for team_kind, timing in kinds:
        group = []
        for i in range(per_family):
            if wanted and f"{team_kind}-{timing}-{i}" not in wanted:
                continue
            sc = generate(team_kind, timing, i, seed)
            if config is not None:
                sc = msgspec.structs.replace(sc, config=config)
            group.append(run_scenario(sc, policy=policy, seeds=seeds, seed=seed + i, exact_nodes=exact_nodes,
                                      exact_seconds=exact_seconds, online_seconds=online_seconds))
            if progress:
                progress(len(scenarios) + len(group), total)
        if not group:
            continue
        scenarios.extend(group)
        rows.append(_row(f"{team_kind}-{timing}", group))
    if len(rows) > 1:
        rows.append(_row("all", scenarios))
    changed = {} if config is None else {k: getattr(config, k) for k in config.__struct_fields__
                                         if getattr(config, k) != getattr(RampsConfig(), k)}
    return SweepReport(family=family, policy=policy, settings=changed, seed=seed, seeds_per_scenario=seeds, families=rows,
                       scenarios=scenarios, wall_seconds=_wallclock.perf_counter() - started)
