"""Load that comes after placement, and relocation, on real processes: ``ramps testbed experiment relocation``.

How this works: the same experiment as ``ramps sim relocation``
(``ramps.experiments.late_load``), on a testbed of real ``ramps node``
processes. ``robots`` emulated robots of
``cores`` cores (``quota`` host cores each); robot r1 submits ``programs``
``burn`` programs of ``seconds`` seconds each (alone on an emulated core),
0.05 s apart; ``load_at`` seconds after the first, r1's own software starts
``busy`` CPU-bound processes. Each variant runs on a fresh testbed whose
nodes are configured for it (``Testbed(config=...)``):

* ``relocation off``: ``[core] relocate = false``, programs stay where they were placed;
* ``relocation``: the default, programs restart elsewhere from their parameters;
* ``relocation + checkpoints``: the burns also save their place every
  ``checkpoint_every`` seconds (``burn(checkpoint_every=...)``) and resume from it.

The nodes' workers run at nice 0 here (``worker_nice = 0``), so a program and
a busy process share a core equally, as in the simulator's experiment (by
default workers run at nice 10 and yield to the robot's own software, which
makes staying on a busy robot even slower). Each variant's makespan is
printed beside the simulator's (median of ``seeds``, the same team, programs,
load and report period, work in seconds) and the hindsight optimum (the
best static split for someone who knew the load was coming, processor
sharing, no transfer times). Every program's one result is checked: a
checkpointed burn must end with an uninterrupted burn's checksum.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import msgspec

from ramps.experiments.late_load import VARIANTS as SIM_VARIANTS
from ramps.experiments.late_load import hindsight_optimum, scenario
from ramps.sim.engine import simulate
from ramps.sim.scenario import PublisherSpec

if TYPE_CHECKING:
    from ramps.testbed import Testbed

VARIANTS = tuple(v for v in SIM_VARIANTS if v != "round robin")
SPACING = 0.05


class RelocationCase(msgspec.Struct, kw_only=True):
    variant: str
    #: testbed: seconds from the first submission to the last result, and where each program ended (r1 first)
    makespan: float
    distribution: list[int]
    moves: int
    resumed: int
    completed: int
    failed: int
    #: results whose checksum is not an uninterrupted burn's (must be 0)
    wrong: int
    #: simulator, same configuration: median over the seeds, with its moves
    sim_makespan: float
    sim_distribution: list[int]
    sim_moves: int
    #: testbed / simulator, and each against the hindsight optimum
    ratio: float
    ratio_optimum: float
    sim_ratio_optimum: float
    #: how much longer than ``seconds`` the programs that never met the load took (median; the
    #: host's CPU drift: the robots ran at 1/host_factor of the speed measured at the start),
    #: the simulator at that speed, and the testbed against it
    host_factor: float = 1.0
    sim_corrected: float = 0.0
    corrected_ratio: float = 0.0


class RelocationReport(msgspec.Struct, kw_only=True):
    robots: int
    cores: int
    quota: float
    speed: float
    programs: int
    seconds: float
    load_at: float
    busy: int
    checkpoint_every: float
    hindsight_optimum: float
    optimum_distribution: list[int]
    cases: list[RelocationCase]
    wall_seconds: float = 0.0


def simulate_variant(variant: str, *, robots: int, cores: int, programs: int, seconds: float, busy: int,
                     load_at: float, checkpoint_every: float, seeds: int,
                     speed: float = 1.0) -> tuple[float, list[int], int]:
    """The simulator's median makespan, a distribution and the moves of that seed; ``speed``
    below 1: robots that run a program of ``seconds`` in ``seconds / speed``."""
    runs = []
    for s in range(seeds):
        sc = scenario(variant, robots=robots, cores=cores, programs=programs, work=seconds, loaded="r1",
                      busy=busy, load_at=load_at, checkpoint_every=checkpoint_every, seed=1000 + s)
        # the node's report period, as ramps.lab.sweeps does
        sc = msgspec.structs.replace(sc, publisher=PublisherSpec(period=1.0, window=1.0),
                                     robots=[msgspec.structs.replace(r, speed=speed) for r in sc.robots])
        res = simulate(sc)
        if res.lost or res.duplicated or res.completed != programs:
            raise RuntimeError(f"the simulator lost or duplicated programs in {variant!r} seed {res.seed}")
        runs.append((res.makespan, [res.distribution.get(f"r{i}", 0) for i in range(1, robots + 1)],
                     sum(st.moves for st in res.statistics)))
    runs.sort(key=lambda r: r[0])
    return runs[len(runs) // 2]


def run_testbed_relocation(*, robots: int = 3, cores: int = 4, quota: float = 0.2, programs: int = 8,
                           seconds: float = 30.0, load_at: float = 6.0, busy: int = 8,
                           checkpoint_every: float = 2.0, seeds: int = 3, timeout: float = 600.0,
                           variants: tuple[str, ...] = VARIANTS, keep_logs: Path | None = None,
                           told_speed: bool = False,
                           log: Callable[[str], None] | None = None) -> RelocationReport:
    """Each variant on a fresh testbed and in the simulator (module docstring)."""
    from ramps.programs.burn import burn
    from ramps.testbed import Testbed
    from ramps.lab.experiments import _keep, identical_speed

    log = log or (lambda _m: None)
    _check(variants, robots=robots, programs=programs, load_at=load_at, seconds=seconds, busy=busy)
    started = time.monotonic()
    speed = identical_speed(1, cores, quota)
    units = round(seconds * speed, 4)
    every = round(checkpoint_every * speed, 4)
    expected = burn(units=units)["checksum"]
    opt, split = hindsight_optimum(robots, cores, programs, seconds, 0, busy, load_at)
    log(f"one emulated core runs {speed:.4f} units/s: programs of {units:g} units ({seconds:g} s alone); "
        f"hindsight optimum {opt:.1f} s ({'-'.join(map(str, split))})")
    cases = []
    for variant in variants:
        sim, sim_dist, sim_moves = simulate_variant(variant, robots=robots, cores=cores, programs=programs,
                                                    seconds=seconds, busy=busy, load_at=load_at,
                                                    checkpoint_every=checkpoint_every, seeds=seeds)
        config = {"worker_nice": 0, "core": {"relocate": variant != "relocation off"}}
        with Testbed(robots, cores=cores, quota=quota, speed=speed if told_speed else None, config=config) as tb:
            team = tb.client("r1", timeout=30.0)
            try:
                kwargs = {"units": units, **({"checkpoint_every": every} if "checkpoints" in variant else {})}
                futures, ok, submitted, ends, t0 = _run_programs(tb, team, programs=programs, units=units,
                                                                 kwargs=kwargs, load_at=load_at, busy=busy,
                                                                 timeout=timeout)
                span = (max(ends.values()) - t0) if len(ok) == programs else float("nan")
                # programs that ran where no load came, start to end: how fast the host really ran them
                clean = [ends[i] - submitted[i] for i, f in enumerate(futures)
                         if f in ok and f.host != "r1" and f.attempts == 1 and i in ends]
                factor = statistics.median(clean) / seconds if clean else 1.0
                corrected = simulate_variant(variant, robots=robots, cores=cores, programs=programs,
                                             seconds=seconds, busy=busy, load_at=load_at,
                                             checkpoint_every=checkpoint_every, seeds=seeds, speed=1.0 / factor)[0]
                case = RelocationCase(
                    variant=variant, makespan=round(span, 2),
                    distribution=[sum(1 for f in ok if f.host == f"r{i}") for i in range(1, robots + 1)],
                    moves=sum(f.moves for f in ok), resumed=sum(1 for f in ok if f.resumed_from is not None),
                    completed=len(ok), failed=programs - len(ok),
                    wrong=sum(1 for f in ok if f.result()["checksum"] != expected),
                    sim_makespan=round(sim, 2), sim_distribution=sim_dist, sim_moves=sim_moves,
                    ratio=round(span / sim, 3), ratio_optimum=round(span / opt, 3),
                    sim_ratio_optimum=round(sim / opt, 3), host_factor=round(factor, 3),
                    sim_corrected=round(corrected, 2), corrected_ratio=round(span / corrected, 3))
                log(f"  {variant:26s} testbed {span:6.1f} s ({'-'.join(map(str, case.distribution))}, "
                    f"{case.moves} moves, {case.resumed} resumed), simulator {sim:6.1f} s "
                    f"({'-'.join(map(str, sim_dist))}, {sim_moves} moves): ratio {case.ratio:.2f}; the host ran "
                    f"programs {factor:.2f}x slower than measured, the simulator at that speed {corrected:.1f} s: "
                    f"ratio {case.corrected_ratio:.2f}")
                cases.append(case)
            finally:
                team.close()
                if keep_logs is not None:
                    _keep(tb, Path(keep_logs) / variant.replace(" ", "-").replace("+", "and"))
    return RelocationReport(robots=robots, cores=cores, quota=quota, speed=speed, programs=programs,
                            seconds=seconds, load_at=load_at, busy=busy, checkpoint_every=checkpoint_every,
                            hindsight_optimum=round(opt, 2), optimum_distribution=split, cases=cases,
                            wall_seconds=round(time.monotonic() - started, 1))


def _check(variants: tuple[str, ...], *, robots: int, programs: int, load_at: float, seconds: float,
           busy: int) -> None:
    """The experiment's arguments make sense, before any testbed starts."""
    bad = [v for v in variants if v not in VARIANTS]
    if bad or not variants:
        raise ValueError(f"variants must be some of {', '.join(VARIANTS)}, got {list(variants)}")
    if robots < 2 or programs < 1 or not 0 < load_at < seconds or busy < 1:
        raise ValueError("need robots >= 2, programs >= 1, busy >= 1 and 0 < load_at < seconds")


def _run_programs(tb: Testbed, team: Any, *, programs: int, units: float, kwargs: dict[str, Any], load_at: float,
                  busy: int, timeout: float) -> tuple[list[Any], list[Any], list[float], dict[int, float], float]:
    """Submit ``programs`` burns from r1, ``SPACING`` apart; load r1 with ``busy`` processes
    ``load_at`` seconds in; wait for them all, cancelling those unfinished after ``timeout``.
    Returns (futures, those that succeeded, submission times, end times by index, start)."""
    futures: list[Any] = []
    submitted: list[float] = []
    ends: dict[int, float] = {}
    t0 = time.monotonic()
    for i in range(programs):
        submitted.append(time.monotonic())
        futures.append(team.options(work=units).submit("burn", **kwargs))
        futures[-1].add_done_callback(lambda _f, i=i: ends.setdefault(i, time.monotonic()))
        time.sleep(max(0.0, t0 + (i + 1) * SPACING - time.monotonic()))
    time.sleep(max(0.0, t0 + load_at - time.monotonic()))
    tb.add_load("r1", busy)
    deadline = t0 + timeout
    while not all(f.done() for f in futures) and time.monotonic() < deadline:
        time.sleep(0.2)
    ok = [f for f in futures if f.done() and f.exception() is None]
    for f in futures:
        if not f.done():
            f.cancel()
    return futures, ok, submitted, ends, t0


def format_report(rep: RelocationReport) -> str:
    lines = [(f"{rep.robots} robots of {rep.cores} cores on {rep.quota:g} host cores; r1 submits {rep.programs} "
              f"programs of {rep.seconds:g} s and gets {rep.busy} busy processes {rep.load_at:g} s in; "
              f"hindsight optimum {rep.hindsight_optimum:.1f} s ({'-'.join(map(str, rep.optimum_distribution))})"),
             (f"{'variant':26s} {'testbed s':>9s} {'vs opt':>6s} {'moves':>5s} {'resumed':>7s}  {'simulator s':>11s} "
              f"{'vs opt':>6s} {'moves':>5s}  {'ratio':>5s}  {'host':>5s} {'sim at host':>11s} {'ratio':>5s}  "
              "testbed / simulator distribution")]
    for c in rep.cases:
        lines.append(f"{c.variant:26s} {c.makespan:9.1f} {c.ratio_optimum:6.3f} {c.moves:5d} {c.resumed:7d}  "
                     f"{c.sim_makespan:11.1f} {c.sim_ratio_optimum:6.3f} {c.sim_moves:5d}  {c.ratio:5.2f}  "
                     f"{c.host_factor:5.2f} {c.sim_corrected:11.1f} {c.corrected_ratio:5.2f}  "
                     f"{'-'.join(map(str, c.distribution))} / {'-'.join(map(str, c.sim_distribution))}"
                     + (f"  ({c.failed} failed)" if c.failed else "") + (f"  ({c.wrong} WRONG)" if c.wrong else ""))
    lines.append("ratio = testbed / simulator; vs opt = against the hindsight optimum; host = how much longer "
                 "than measured the host took for programs the load never met (its CPU drift), and the "
                 f"simulator with robots that much slower; {rep.wall_seconds:.0f} s")
    return "\n".join(lines)


__all__ = ["RelocationCase", "RelocationReport", "VARIANTS", "format_report", "run_testbed_relocation"]
