"""Accelerator placement: ramps, blind to accelerators, and round robin against the exact optimum.

How this works: ``generate`` makes one reproducible scenario of the family:
a team of 2-6 robots of mixed cores (1-4) and speeds (0.5-2), one to three
of them with 1-2 ``cuda`` slots of speed 5-30, one to three of them origins
submitting all their programs at once. Each origin submits one to three
kinds of program: CPU-only ones (5-30 work units), and ones that can use
the accelerator with a speed-up of 1x to 30x on a speed-20 slot (their
accelerator work is ``work * 20 / speedup``; a slot of speed 5 makes a 1x
program four times slower than a speed-1 core). The scenario's kind
(``FAMILIES``, by index) adds:

- ``mixed``: nothing more;
- ``strict``: some accelerator programs may not run on a CPU
  (``cpu_fallback`` False);
- ``misdeclared``: accelerator programs declare an accelerator work 4x
  below to 4x above their true one (the simulator runs the true one);
- ``crash`` / ``cut``: an accelerator robot that is no origin crashes, or
  is cut off for good, 0.5-4 s after the release.

``run_family`` simulates each scenario on its own seed with ``VARIANTS``:
``ramps``; ``ramps_blind``, the same nodes whose placement prices every
robot by the program's CPU work (``BlindPolicy``: a program still runs on
the accelerator where it lands, as the product runs it); and round robin;
and compares each makespan with ``ramps.experiments.accel_optimum`` (the
CP-SAT optimum of the same batch, or its lower bound where the solver
proves nothing within ``exact_seconds``: ``proven`` says which). Beside
them, ``greedy``: ramps' rule (each program where it ends first, in
submission order) with a perfect, instant view, in the optimum's model:
what is left between it and ramps is what the origins did not know when
they placed (several origins at once, stale reports, declarations, faults),
what is left between it and the optimum is the rule's; ``greedy_declared``,
the same rule choosing by the accelerator work the programs declare,
separates the declarations from the rest.

A second reference, ``declared``: the CP-SAT optimum of the same scenario
with each program's declared accelerator work (``told_declarations``), its
placement then priced with the true work (``accel_optimum.makespan_of``).
It is what a planner that knows every robot, program and release but only
the declarations could best do: a reference, not a bound (a placement that
learns can end before it). Where nothing is mis-declared it is the true
optimum. Each summary gives ramps' ratios to it beside those to the true
optimum, never instead of them.
"""

from __future__ import annotations

import math
import random
import statistics
from collections.abc import Callable, Sequence
from typing import Any

import msgspec

from ramps.core.policy import RampsPolicy
from ramps.experiments.accel_optimum import greedy, makespan_of, optimum
from ramps.sim.engine import Simulator
from ramps.sim.results import SimResult
from ramps.sim.scenario import FaultSpec, ProgramSpec, RobotSpec, Scenario

FAMILIES = ("mixed", "strict", "misdeclared", "crash", "cut")
#: the placements compared on each scenario
VARIANTS = ("ramps", "ramps_blind", "round_robin")
#: what the command says of the ``declared`` reference
DECLARED_NOTE = ("told: the CP-SAT optimum given only the declared accelerator work, its placement timed with "
                 "the true work; what an origin told only the declarations could best do, a reference and not a "
                 "bound (a placement that learns can beat it)")
#: the speed of the slot a program's speed-up is stated for
REFERENCE_SLOT = 20.0


class BlindPolicy(RampsPolicy):
    """ramps' placement without the accelerator feature: every robot priced by
    the program's CPU work (the host still runs it on its accelerator). An
    experiment's variant, never a node's policy."""

    name = "ramps_blind"

    def choose(self, req: Any, *args: Any, **kw: Any) -> Any:
        return super().choose(msgspec.structs.replace(req, accelerator="", accelerator_work=0.0), *args, **kw)

    def pools(self, req: Any, *args: Any, **kw: Any) -> Any:
        return super().pools(msgspec.structs.replace(req, accelerator="", accelerator_work=0.0), *args, **kw)


class _BlindSimulator(Simulator):
    """The simulator with ``BlindPolicy`` in every node (one instance each)."""

    def _boot(self, r: Any, now: float) -> None:
        super()._boot(r, now)
        blind = BlindPolicy()
        r.node.policy = blind
        r.node.origin.policy = blind


def simulate_variant(sc: Scenario, variant: str, seed: int, *, trace: bool = False) -> SimResult:
    """``sc`` simulated with one of ``VARIANTS`` on ``seed``."""
    if variant == "ramps_blind":
        return _BlindSimulator(sc, policy="ramps", seed=seed, trace=trace).run()
    return Simulator(sc, policy=variant, seed=seed, trace=trace).run()


def _speedup(rng: random.Random) -> float:
    """1x to 30x, spread evenly on a log scale."""
    return round(math.exp(rng.uniform(0.0, math.log(30.0))), 1)


def _team(rng: random.Random, family: str) -> tuple[list[RobotSpec], list[str], str | None]:
    """The robots, the origins, and the robot that fails (failure families)."""
    n = rng.randint(2, 6)
    names = [f"r{i}" for i in range(1, n + 1)]
    origins = rng.sample(names, rng.randint(1, min(3, n - 1 if family in ("crash", "cut") else n)))
    gpus = set(rng.sample(names, rng.randint(1, min(3, n))))
    failing = None
    if family in ("crash", "cut"):
        spare = [r for r in names if r not in origins]
        failing = rng.choice(spare)
        gpus.add(failing)
    robots = []
    for name in names:
        accel = [f"cuda:{rng.choice((1, 1, 2))}:{rng.choice((5, 10, 15, 20, 30))}"] if name in gpus else []
        robots.append(RobotSpec(name=name, cores=rng.choice((1, 2, 2, 4)), speed=rng.choice((0.5, 1.0, 1.0, 1.5, 2.0)),
                                accelerators=accel))
    return robots, origins, failing


def generate(index: int, seed: int = 0) -> Scenario:
    """One reproducible scenario of the family (its kind: ``FAMILIES[index % 5]``)."""
    family = FAMILIES[index % len(FAMILIES)]
    rng = random.Random(f"{seed}/accelerators/{index}")
    robots, origins, failing = _team(rng, family)
    programs: list[ProgramSpec] = []
    budget = 16  # programs in all, for the exact reference
    for origin in origins:
        for _ in range(rng.randint(1, 3)):
            count = min(rng.randint(1, 5), budget)
            if count <= 0:
                break
            budget -= count
            work = round(rng.uniform(5.0, 30.0), 1)
            if rng.random() < 0.35:
                programs.append(ProgramSpec(program="plan", origin=origin, count=count, work=work))
                continue
            accel_work = round(work * REFERENCE_SLOT / _speedup(rng), 2)
            strict = family == "strict" and rng.random() < 0.5
            estimate = None
            if family == "misdeclared":
                estimate = round(accel_work * math.exp(rng.uniform(-math.log(4.0), math.log(4.0))), 2)
            programs.append(ProgramSpec(program="detect", origin=origin, count=count, work=work, accelerator="cuda",
                                        accelerator_work=accel_work, accelerator_estimate=estimate,
                                        cpu_fallback=not strict))
    faults = []
    if failing is not None:
        faults.append(FaultSpec(at=round(rng.uniform(0.5, 4.0), 2), robot=failing,
                                kind="crash" if family == "crash" else "network"))
    return Scenario(name=f"accelerators-{family}-{index}", seed=rng.getrandbits(32), robots=robots,
                    programs=programs, faults=faults).check()


def family_of(sc: Scenario) -> str:
    """The kind of a generated scenario, from its name."""
    return sc.name.split("-")[1]


class AccelRow(msgspec.Struct, kw_only=True):
    scenario: str
    family: str
    programs: int
    #: per variant: makespan (s), programs completed
    makespan: dict[str, float]
    completed: dict[str, int]
    #: the reference: the optimum's makespan if proven, else its lower bound
    reference: float
    proven: bool
    optimum: float
    bound: float
    #: makespan / reference per variant, for ``greedy`` and for
    #: ``greedy_declared`` (the rule choosing by the declared accelerator
    #: work; inf where a variant did not complete every program)
    ratio: dict[str, float]
    #: the model's makespan of ramps' rule with a perfect view (``accel_optimum.greedy``)
    greedy: float = 0.0
    #: the reference told only the declarations: the model's makespan, with the
    #: true work, of the CP-SAT optimum's placement for the declared work (the
    #: true optimum's makespan where nothing is mis-declared)
    declared: float = 0.0
    #: CP-SAT proved that placement optimal for the declared work
    declared_proven: bool = True
    #: makespan / ``declared`` per simulated variant (inf where it left
    #: programs undone)
    ratio_declared: dict[str, float] = msgspec.field(default_factory=dict)


class Against(msgspec.Struct, kw_only=True):
    """Each variant's ratios to one reference over a set of scenarios."""

    median: dict[str, float]
    worst: dict[str, float]
    #: scenarios with a ratio of at most 1.03, and at most 1.10
    within_3: dict[str, int]
    within_10: dict[str, int]
    incomplete: dict[str, int]


class AccelSummary(msgspec.Struct, kw_only=True):
    """One family's (or all scenarios') ratios to the reference."""

    family: str
    scenarios: int
    proven: int
    median: dict[str, float]
    worst: dict[str, float]
    #: scenarios where the variant left programs undone
    incomplete: dict[str, int]
    #: scenarios with a ratio to the reference of at most 1.03, and at most 1.10
    within_3: dict[str, int] = msgspec.field(default_factory=dict)
    within_10: dict[str, int] = msgspec.field(default_factory=dict)
    #: the simulated variants' ratios to the ``declared`` reference, beside
    #: those to the true optimum above
    declared: Against | None = None
    #: scenarios whose ``declared`` placement CP-SAT proved optimal
    declared_proven: int = 0


class AccelReport(msgspec.Struct, kw_only=True):
    seed: int
    exact_seconds: float
    rows: list[AccelRow]
    summaries: list[AccelSummary]


def run_scenario(sc: Scenario, *, exact_seconds: float = 2.0, variants: Sequence[str] = VARIANTS) -> AccelRow:
    """Every variant on ``sc``'s seed, against the CP-SAT reference."""
    opt = optimum(sc, time_limit=exact_seconds)
    reference = opt.makespan if opt.proven else opt.bound
    total = sum(p.count for p in sc.programs)
    makespan, completed, ratio = {}, {}, {}
    for v in variants:
        res = simulate_variant(sc, v, sc.seed)
        makespan[v], completed[v] = res.makespan, res.completed
        ratio[v] = res.makespan / reference if res.completed == total and reference > 0 else math.inf
    rule = greedy(sc)[0]
    ratio["greedy"] = rule / reference if reference > 0 else math.inf
    ratio["greedy_declared"] = greedy(sc, declared=True)[0] / reference if reference > 0 else math.inf
    declared, declared_proven = opt.makespan, opt.proven
    if any(p.accelerator_estimate is not None for p in sc.programs):
        told = optimum(told_declarations(sc), time_limit=exact_seconds)
        declared, declared_proven = makespan_of(sc, told.hosts), told.proven
    ratio_declared = {v: makespan[v] / declared if completed[v] == total and declared > 0 else math.inf
                      for v in variants}
    return AccelRow(scenario=sc.name, family=family_of(sc), programs=total, makespan=makespan, completed=completed,
                    reference=reference, proven=opt.proven, optimum=opt.makespan, bound=opt.bound, ratio=ratio,
                    greedy=rule, declared=declared, declared_proven=declared_proven, ratio_declared=ratio_declared)


def told_declarations(sc: Scenario) -> Scenario:
    """``sc`` with each program's accelerator work replaced by the one it
    declares (``accelerator_estimate``, where it declares one)."""
    return msgspec.structs.replace(sc, programs=[
        msgspec.structs.replace(p, accelerator_work=p.accelerator_estimate) if p.accelerator_estimate is not None
        else p for p in sc.programs])


def _against(rows: Sequence[AccelRow], variants: Sequence[str], ratios: Callable[[AccelRow], dict[str, float]]
             ) -> Against:
    """Median, worst, within 3% and 10%, and undone of ``ratios(row)`` per variant."""
    return Against(
        median={v: statistics.median(ratios(r)[v] for r in rows) if rows else math.nan for v in variants},
        worst={v: max((ratios(r)[v] for r in rows), default=math.nan) for v in variants},
        within_3={v: sum(1 for r in rows if ratios(r)[v] <= 1.03) for v in variants},
        within_10={v: sum(1 for r in rows if ratios(r)[v] <= 1.10) for v in variants},
        incomplete={v: sum(1 for r in rows if math.isinf(ratios(r)[v])) for v in variants})


def summarise(rows: Sequence[AccelRow], family: str,
              variants: Sequence[str] = (*VARIANTS, "greedy", "greedy_declared")) -> AccelSummary:
    """Median, worst, within 3% and 10% per variant (and ``greedy``) over
    ``rows``, to the true optimum and, for the simulated variants, to the
    ``declared`` reference."""
    true = _against(rows, variants, lambda r: r.ratio)
    simulated = [v for v in variants if all(v in r.ratio_declared for r in rows)]
    return AccelSummary(
        family=family, scenarios=len(rows), proven=sum(r.proven for r in rows), median=true.median,
        worst=true.worst, incomplete=true.incomplete, within_3=true.within_3, within_10=true.within_10,
        declared=_against(rows, simulated, lambda r: r.ratio_declared),
        declared_proven=sum(r.declared_proven for r in rows))


def run_family(count: int = 220, *, seed: int = 0, exact_seconds: float = 2.0,
               progress: Callable[[int, int], None] | None = None) -> AccelReport:
    """The first ``count`` scenarios of the family, every variant on each,
    summarised per kind and over all."""
    rows = []
    for i in range(count):
        rows.append(run_scenario(generate(i, seed), exact_seconds=exact_seconds))
        if progress is not None:
            progress(i + 1, count)
    summaries = [summarise([r for r in rows if r.family == f], f) for f in FAMILIES if any(r.family == f for r in rows)]
    summaries.append(summarise(rows, "all"))
    return AccelReport(seed=seed, exact_seconds=exact_seconds, rows=rows, summaries=summaries)


def print_accelerators(report: AccelReport, console: Any) -> None:
    """The summary tables: median and worst ratio to the reference per kind and
    variant; then ramps' ratios to the true optimum beside those to the
    optimum told the declarations, and a line on what that reference is."""
    from rich.table import Table

    table = Table(title=f"accelerator placement, makespan / CP-SAT optimum (or / its bound where not proven), "
                        f"median and worst; seed {report.seed}, {report.exact_seconds:g} s per proof",
                  title_justify="left", pad_edge=False)
    shown = {"ramps": "ramps", "ramps_blind": "ramps blind", "round_robin": "round robin",
             "greedy": "rule, perfect view", "greedy_declared": "rule, declared work"}
    for name in ("kind", "scenarios", "optimal", *shown.values()):
        table.add_column(name, justify="left" if name == "kind" else "right", no_wrap=True)
    for s in report.summaries:
        if s.family == "all":
            table.add_section()
        cells = [s.family, str(s.scenarios), str(s.proven)]
        for v in shown:
            undone = f" ({s.incomplete[v]} undone)" if s.incomplete[v] else ""
            cells.append(f"{s.median[v]:.3f} / {s.worst[v]:.3f}{undone}")
        table.add_row(*cells)
    console.print(table)
    _print_declared(report, console)


def _print_declared(report: AccelReport, console: Any) -> None:
    """ramps' ratios to the true optimum beside those to the optimum told the
    declarations, per kind."""
    from rich.table import Table

    table = Table(title="ramps over the optimum and over the optimum told the declarations (median / worst; "
                        "within 3% / 10%)", title_justify="left", pad_edge=False)
    for name in ("kind", "scenarios", "ramps / optimum", "within 3% / 10%", "told: optimal", "ramps / told",
                 "within 3% / 10%"):
        table.add_column(name, justify="left" if name == "kind" else "right", no_wrap=True)
    for s in report.summaries:
        if s.family == "all":
            table.add_section()
        cells = [s.family, str(s.scenarios), f"{s.median['ramps']:.3f} / {s.worst['ramps']:.3f}",
                 f"{s.within_3['ramps']} / {s.within_10['ramps']}", str(s.declared_proven)]
        if s.declared is not None and "ramps" in s.declared.median:
            d = s.declared
            cells += [f"{d.median['ramps']:.3f} / {d.worst['ramps']:.3f}",
                      f"{d.within_3['ramps']} / {d.within_10['ramps']}"]
        table.add_row(*cells)
    console.print(table)
    console.print(DECLARED_NOTE, soft_wrap=True)
