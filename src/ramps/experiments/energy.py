"""Makespan against energy as placement weighs energy: ``ramps sim energy``.

How this works: one team of three kinds of robot (``TEAM``), fast ones
that burn watts, middling ones, and slow, frugal ones, each stating its
power per busy core; three origins submit a burst of programs each. The
same scenario runs once per ``RampsConfig.energy_weight`` in ``WEIGHTS``
(0: the earliest finish; 1: the fewest joules per unit of work, see
``ramps.core.battery``), on ``seeds`` seeds, and each point of the curve
is the median makespan and the median energy (every robot's busy
core-seconds times its power, ``SimResult.energy``) of its runs. Round
robin on the same seeds is printed beside it. Robots' batteries start full
and drain little, so the reserve never acts: this is the trade-off alone.

Rules: seeded and deterministic like every simulator experiment.
"""

from __future__ import annotations

import statistics
from collections.abc import Callable, Sequence

import msgspec

from ramps.core.config import RampsConfig
from ramps.sim.engine import simulate
from ramps.sim.scenario import ProgramSpec, RobotSpec, Scenario

#: (name template, how many, cores, speed, watts per busy core): joules per
#: work unit are watts / speed: 10, 6 and 3
TEAM: tuple[tuple[str, int, int, float, float], ...] = (
    ("fast{i}", 2, 4, 2.0, 20.0),
    ("mid{i}", 2, 4, 1.0, 6.0),
    ("frugal{i}", 2, 2, 0.8, 2.4),
)
WEIGHTS = (0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 1.0)


class EnergyPoint(msgspec.Struct, kw_only=True):
    #: the energy weight (None: round robin)
    weight: float | None
    policy: str
    #: medians over the seeds: seconds from the first submission to the last
    #: delivery, joules used, and the share of the work each kind of robot ran
    makespan: float
    energy: float
    work_share: dict[str, float]
    runs: int
    lost: int = 0
    duplicated: int = 0


class EnergyReport(msgspec.Struct, kw_only=True):
    team: list[list[float | int | str]]
    programs: int
    work: float
    seeds: int
    #: the curve, weight by weight, then round robin
    points: list[EnergyPoint]


def scenario(weight: float, *, programs: int = 8, work: float = 30.0, seed: int = 0) -> Scenario:
    """The team of ``TEAM``; ``fast1``, ``mid1`` and ``frugal1`` each submit
    ``programs`` programs of ``work`` units, 0.05 s apart, at once."""
    robots = [RobotSpec(name=name, count=count, cores=cores, speed=speed, power=watts, battery=1.0, drain=1e-5)
              for name, count, cores, speed, watts in TEAM]
    origins = [name.format(i=1) for name, *_ in TEAM]
    return Scenario(name=f"energy-{weight:g}", seed=seed, robots=robots,
                    programs=[ProgramSpec(origin=o, count=programs, work=work, spacing=0.05) for o in origins],
                    config=RampsConfig(energy_weight=weight))


def _point(weight: float | None, policy: str, runs: list, programs: int) -> EnergyPoint:
    kinds = [name.split("{")[0] for name, *_ in TEAM]
    shares = {k: statistics.median(sum(n for r, n in res.distribution.items() if r.startswith(k)) / programs
                                   for res in runs) for k in kinds}
    return EnergyPoint(weight=weight, policy=policy, makespan=round(statistics.median(r.makespan for r in runs), 2),
                       energy=round(statistics.median(sum(r.energy.values()) for r in runs), 1),
                       work_share={k: round(v, 3) for k, v in shares.items()}, runs=len(runs),
                       lost=sum(r.lost for r in runs), duplicated=sum(r.duplicated for r in runs))


def run_curve(weights: Sequence[float] = WEIGHTS, *, seeds: int = 3, programs: int = 8, work: float = 30.0,
              seed: int = 0, progress: Callable[[int, int], None] | None = None) -> EnergyReport:
    """The curve (module docstring): one point per weight, then round robin."""
    points = []
    total = (len(weights) + 1) * seeds
    done = 0
    for weight in list(weights) + [None]:
        runs = []
        for s in range(seeds):
            sc = scenario(weight or 0.0, programs=programs, work=work, seed=seed + s)
            runs.append(simulate(sc, policy="round_robin" if weight is None else "ramps"))
            done += 1
            if progress is not None:
                progress(done, total)
        points.append(_point(weight, "round_robin" if weight is None else "ramps", runs, 3 * programs))
    return EnergyReport(team=[list(t) for t in TEAM], programs=3 * programs, work=work, seeds=seeds, points=points)


def format_report(rep: EnergyReport) -> str:
    kinds = [str(t[0]).split("{")[0] for t in rep.team]
    team = ", ".join(f"{t[1]} x {kind} ({t[2]} cores, speed {t[3]:g}, {t[4]:g} W a core, "
                     f"{float(t[4]) / float(t[3]):g} J a unit)" for t, kind in zip(rep.team, kinds))
    base = rep.points[0]
    lines = [f"{rep.programs} programs of {rep.work:g} units from 3 origins on {team}; median of {rep.seeds} seeds",
             f"{'weight':>8s} {'makespan s':>10s} {'energy J':>9s} {'vs w=' + format(base.weight or 0, 'g'):>14s}  "
             + "  ".join(f"{k:>7s}" for k in kinds)]
    for p in rep.points:
        label = "rr" if p.weight is None else f"{p.weight:g}"
        lines.append(f"{label:>8s} {p.makespan:10.1f} {p.energy:9.0f} "
                     f"{p.makespan / base.makespan:6.2f}x {p.energy / base.energy:5.2f}x  "
                     + "  ".join(f"{100 * p.work_share[k]:6.0f}%" for k in kinds)
                     + (f"  ({p.lost} lost, {p.duplicated} duplicated)" if p.lost or p.duplicated else ""))
    lines.append("vs: makespan and energy against the first weight; the last columns: the share of the programs "
                 "each kind of robot ran (rr: round robin)")
    return "\n".join(lines)
