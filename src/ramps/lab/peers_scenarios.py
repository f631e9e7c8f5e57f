"""The peers experiment's scenarios, its records, the ideal and the report.

How this works: a ``PeerScenario`` is a team of emulated robots, some of
them busy with ``BUSY`` processes of their own, and a burst of identical
``burn`` programs from one or more origins (each submits ``SPACING`` s
apart, all at the same moments), maybe with one robot crashed ``crash_at``
s after the first submission; ``SCENARIOS`` are the issue's. An engine's
run of one is an ``EngineRun`` (makespan, distribution, programs lost), a
scenario's runs a ``ScenarioResult``, the whole a ``PeersReport``, which
``format_report`` prints. ``ideal`` is the best schedule of the
processor-sharing model found by ``ramps.experiments.optimum``'s local
search and annealing from the oracle's, for the scenario's releases on
robots of a measured speed: a busy robot's ``b`` processes count as
``b / nice_weight(worker_nice)`` programs (weighted processor sharing), and
a crashed robot is left out (the ideal knows in hindsight). ``simulated``
is the simulator's ramps for the same configuration.

Rules: pure (no testbed, no processes): these run anywhere.
"""

from __future__ import annotations

import math
import statistics
import time
from collections.abc import Sequence

import msgspec

#: seconds between one origin's submissions (as ``ramps.lab.sweeps``)
SPACING = 0.05
#: busy processes of a busy robot (the testbed's background load)
BUSY = 8
#: the niceness of ramps' program workers (``NodeSettings.worker_nice``), given to Ray's and Dask's too
WORKER_NICE = 10
EXTRA = "pip install -e '.[peers]'  (or: pip install 'ramps-robotics[peers]')"


class PeerScenario(msgspec.Struct, kw_only=True, frozen=True):
    name: str
    description: str
    robots: int = 5
    #: programs in all (split evenly between the origins)
    programs: int = 30
    #: busy robots (``BUSY`` processes each)
    loaded: tuple[str, ...] = ()
    origins: tuple[str, ...] = ("r1",)
    #: seconds after the first submission when a robot running programs is crashed (None: none)
    crash_at: float | None = None

    @property
    def names(self) -> list[str]:
        return [f"r{i}" for i in range(1, self.robots + 1)]

    def per_origin(self) -> int:
        return max(1, self.programs // len(self.origins))

    def with_programs(self, programs: int | None) -> "PeerScenario":
        return self if programs is None else msgspec.structs.replace(self, programs=programs)


SCENARIOS: dict[str, PeerScenario] = {s.name: s for s in (
    PeerScenario(name="idle", description="idle robots, programs from r1"),
    PeerScenario(name="busy-1", description="r5 busy (8 busy processes), programs from r1", loaded=("r5",)),
    PeerScenario(name="busy-2", description="r4 and r5 busy, programs from r1", loaded=("r4", "r5")),
    PeerScenario(name="busy-4", description="r2-r5 busy, programs from r1", loaded=("r2", "r3", "r4", "r5")),
    PeerScenario(name="origins", description="idle robots, r1 and r2 submit half each",
                 origins=("r1", "r2")),
    PeerScenario(name="crash", description="programs from r1; a robot running programs is crashed at 10 s",
                 programs=15, crash_at=10.0),
)}


class EngineRun(msgspec.Struct, kw_only=True):
    engine: str
    #: seconds from the first submission to the last result (None: nothing completed, or not run)
    makespan: float | None = None
    #: programs completed on each robot (the scenario's robots, r1 first)
    distribution: list[int] = []
    completed: int = 0
    lost: int = 0
    #: the robot crashed, and how many programs were running there then
    crashed: str | None = None
    crashed_running: int = 0
    #: work units per second of one emulated core, measured before the run; the ideal at that speed
    speed: float = 0.0
    ideal: float | None = None
    ratio: float | None = None
    host_load: float = 0.0
    wall: float = 0.0
    #: programs still running when the burst's time was up (``Setup.timeout``): no makespan then
    unfinished: int = 0
    #: host cores the busy robots' own software got during the burst, per busy robot (None: none busy):
    #: what the programs' priority protects (a robot's quota is ``Setup.quota``)
    own_cpu: float | None = None
    #: why it did not run, or failed
    error: str | None = None
    #: the round of engines in turns it ran in (1 first; ``run_peers``' ``repeats``)
    round: int = 1


class ScenarioResult(msgspec.Struct, kw_only=True):
    scenario: PeerScenario
    #: the ideal at the first run's speed, and its distribution
    ideal: float | None
    ideal_distribution: list[int]
    #: the simulator's ramps, median of 3 seeds (None with a crash)
    sim: float | None
    runs: list[EngineRun]


class PeersReport(msgspec.Struct, kw_only=True):
    cores: int
    quota: float
    work: float
    worker_nice: int
    scenarios: list[ScenarioResult]
    wall: float = 0.0
    #: rounds of every engine in turns
    repeats: int = 1


class Setup(msgspec.Struct, kw_only=True, frozen=True):
    cores: int = 4
    quota: float = 0.32
    work: float = 1.5
    #: seconds a burst may take (round robin's nice-10 programs beside 8 busy processes take 7-11 minutes)
    timeout: float = 1500.0
    #: niceness of Ray's and Dask's processes (ramps' workers keep the node's ``worker_nice``, 10)
    peer_nice: int = WORKER_NICE
    #: a folder where each ramps run's node logs and traces are kept (``<scenario>-<engine>/``)
    keep_logs: str | None = None


def distribution(hosts: Sequence[str | None], names: Sequence[str]) -> list[int]:
    """Programs per robot (``names`` order) from where each completed program ran (None: lost)."""
    return [sum(1 for h in hosts if h == r) for r in names]


def releases(sc: PeerScenario) -> list[float]:
    """Every program's submission time from the first (the origins submit at the same moments)."""
    return sorted(i * SPACING for _ in sc.origins for i in range(sc.per_origin()))


def ideal(sc: PeerScenario, *, cores: int, speed: float, work: float, worker_nice: int = WORKER_NICE,
          without: Sequence[str] = (), time_limit: float = 3.0) -> tuple[float, list[int]]:
    """The best schedule of the processor-sharing model for the scenario (module docstring),
    without the robots ``without`` (a crashed one): the oracle's, improved by local search and
    annealing (``ramps.experiments.optimum``); its makespan and distribution."""
    from ramps.core.cost import nice_weight
    from ramps.experiments.metrics import Machine
    from ramps.experiments.optimum import anneal, improve
    from ramps.experiments.sweep import oracle_schedule
    from ramps.lab.sweeps import sim_scenario

    names = [r for r in sc.names if r not in without]
    weight = nice_weight(worker_nice)
    team = [Machine(cores, speed, round(BUSY / weight) if r in sc.loaded else 0) for r in names]
    rel = releases(sc)
    # a feasible start: the oracle's on the same team (the simulator's scenario gives its machines)
    sim = sim_scenario(len(names), sc.per_origin(), 0, len(sc.origins), cores=cores, speed=speed, work=work)
    sim = msgspec.structs.replace(sim, robots=[msgspec.structs.replace(s, background=m.background)
                                               for s, m in zip(sim.robots, team)])
    _, start = oracle_schedule(sim, work)
    deadline = time.perf_counter() + time_limit
    span, placed = improve(team, rel, work, start, deadline)
    span, placed = min((span, placed), anneal(team, rel, work, placed, steps=20_000, deadline=deadline))
    counts = [0] * len(team)
    for i in placed:
        counts[i] += 1
    by_name = dict(zip(names, counts))
    return span, [by_name.get(r, 0) for r in sc.names]


def simulated(sc: PeerScenario, *, cores: int, speed: float, work: float) -> float | None:
    """The simulator's ramps for the scenario (``ramps.lab.sweeps.simulate_config``); None with a
    crash, or with busy robots that are not the last ones (the sweeps' configurations)."""
    from ramps.lab.sweeps import simulate_config

    last = sc.names[len(sc.names) - len(sc.loaded):] if sc.loaded else []
    if sc.crash_at is not None or sorted(sc.loaded) != sorted(last) or sc.origins != tuple(sc.names[:len(sc.origins)]):
        return None
    span, _ = simulate_config(sc.robots, sc.per_origin(), len(sc.loaded), len(sc.origins), cores=cores, speed=speed,
                              work=work)
    return round(span, 2)


def victim(running: dict[str, int], origins: Sequence[str]) -> str | None:
    """The robot to crash: of those running programs, not an origin, the one running most (the last on a tie)."""
    cands = [(n, r) for r, n in running.items() if n > 0 and r not in origins]
    return max(cands, key=lambda c: (c[0], c[1]))[1] if cands else None


def medians(runs: Sequence[EngineRun]) -> dict[str, tuple[float, float | None, int]]:
    """engine -> (median makespan, median ratio, rounds) over its runs that
    finished every program (an engine that left programs unfinished or lost
    in any round has none)."""
    by: dict[str, list[EngineRun]] = {}
    for r in runs:
        by.setdefault(r.engine, []).append(r)
    out = {}
    for engine, rs in by.items():
        spans = [r.makespan for r in rs if r.makespan is not None and not r.unfinished and not r.lost]
        if spans and len(spans) == len(rs):
            ratios = [r.ratio for r in rs if r.ratio is not None]
            out[engine] = (statistics.median(spans), statistics.median(ratios) if ratios else None, len(rs))
    return out


def format_report(rep: PeersReport) -> str:
    lines = [f"robots of {rep.cores} emulated cores on {rep.quota:g} host cores, programs of {rep.work:g} units "
             f"of burn; Ray's and Dask's programs at nice {rep.worker_nice} (ramps' workers at the node's "
             f"worker_nice, 10); busy robots run {BUSY} "
             "busy processes"]
    for s in rep.scenarios:
        sc = s.scenario
        ideal_s = f"{s.ideal:.1f} s ({'-'.join(map(str, s.ideal_distribution))})" if s.ideal else "-"
        sim_s = f", simulator's ramps {s.sim:.1f} s" if s.sim else ""
        lines.append(f"\n{sc.name}: {sc.description}; {sc.robots} robots, {sc.per_origin() * len(sc.origins)} "
                     f"programs; ideal {ideal_s}{sim_s}")
        lines.append(f"  {'engine':12s} {'makespan':>9s} {'ideal':>7s} {'ratio':>6s} {'lost':>4s}  "
                     f"{'distribution':16s} notes")
        for r in s.runs:
            if r.error and r.makespan is None:
                lines.append(f"  {r.engine:12s} {'-':>9s} {'-':>7s} {'-':>6s} {'-':>4s}  {'':16s} {r.error}")
                continue
            span = f"{r.makespan:.1f} s" if r.makespan is not None else "-"
            notes = []
            if r.crashed:
                notes.append(f"crashed {r.crashed} with {r.crashed_running} running")
            if r.unfinished:
                notes.append(f"{r.unfinished} not done when the time was up")
            if r.own_cpu is not None:
                notes.append(f"busy robots' own software {r.own_cpu / rep.quota:.0%} of the robot")
            notes.append(f"speed {r.speed:.4f}, host load {r.host_load:.1f}")
            if r.error:
                notes.append(r.error)
            lines.append(f"  {r.engine:12s} {span:>9s} {(r.ideal or 0):7.1f} {(r.ratio or math.nan):6.2f} "
                         f"{r.lost:4d}  {'-'.join(map(str, r.distribution)):16s} {'; '.join(notes)}")
        if rep.repeats > 1:
            med = medians(s.runs)
            lines.append("  medians of rounds in turns: " + ", ".join(
                f"{e} {m[0]:.1f} s (ratio {m[1]:.2f})" if m[1] is not None else f"{e} {m[0]:.1f} s"
                for e, m in med.items()))
            others = [m[0] for e, m in med.items() if not e.startswith("ramps")]
            if "ramps" in med and others:
                lines.append(f"  ramps / the best other engine: {med['ramps'][0] / min(others):.3f}")
    lines.append(f"\nratio: makespan / ideal at the speed measured before that run; {rep.wall:.0f} s in all")
    return "\n".join(lines)

