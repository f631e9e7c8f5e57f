"""The paper's sweeps and several-origins bursts on real processes, beside the simulator.

The real-process twin of ``ramps.experiments.sweep`` (several origins) and
of the sweeps of ``ramps.experiments.paper`` (Tables 3-4).

How this works: a configuration is a team (``robots`` emulated robots of
``cores`` cores on ``quota`` host cores each, the last ``loaded`` of them
running ``stress`` busy processes, as the paper's Table 4) and a burst of
identical ``burn`` programs of ``work`` units from ``origins`` robots (r1,
r2, ...; one origin is the paper's Tables 3-4, several is issue 10's
several-origins burst), each origin submitting its programs 0.05 s apart.
``run_testbed_sweep`` runs every configuration on a testbed of real
``ramps node`` processes (one testbed per team size; busy processes are
added and removed between configurations) and the same configuration in the
simulator (``ramps.sim``: same cores, the speed the testbed measured, the
node's report period, the workers' niceness against the busy load), and
prints both makespans and distributions side by side. The simulator's
fidelity for that configuration is ``ratio`` = testbed / simulator.

Two distributions can be equally good: 15 programs on five robots of four
cores end together whether they go 3-3-3-3-3 or 3-3-3-4-2, each on a core
of its own. So each case also gives the makespan the model assigns each
distribution (``shared_makespan``: identical programs started together, each
robot's shared with its busy processes by weighted processor sharing), and
says whether the testbed's is the simulator's (``same``) or as good by that
model (``as_good``, within ``AS_GOOD``).

The testbed's makespan also carries the host's noise: on this shared 2-core
VM a work unit's CPU cost moves by 10-40% from minute to minute, and other
processes take CPU from the robots. So each configuration also reads the CPU
seconds the programs' workers used on every robot, gives a unit's cost
during the run (``unit_cpu``) against the cost when the speed was measured
(``calibration``), and ``corrected_ratio`` compares the testbed with the
simulator scaled by it. Nor does a busy host give the robots all their
quota: a robot's cgroup competes with every process of the root cgroup as
one entity. So each configuration also reads every robot's cgroup usage
while it ran programs, against what the model gives it (its quota times its
busy emulated cores), and ``starved_ratio`` scales the simulator by the least
fed robot's share too: what is left is the emulation's and the runtime's.

Run ``ramps testbed experiment sweep`` (root; ``--help``): a small
representative subset by default (about 4 minutes), ``--full`` for more.
"""

from __future__ import annotations

import os
import statistics
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import msgspec

from ramps.core.config import RampsConfig
from ramps.core.cost import nice_weight, program_share
from ramps.sim.engine import simulate
from ramps.sim.scenario import ProgramSpec, PublisherSpec, RobotSpec, Scenario
from ramps.lab.speeds import reported_speeds, spread

EXPERIMENTS = ("unloaded", "loaded", "multi-origin")
#: (experiment, robots, programs per origin, loaded robots, origins)
DEFAULT_CONFIGS: list[tuple[str, int, int, int, int]] = [
    ("unloaded", 3, 10, 0, 1),
    ("multi-origin", 3, 6, 0, 2),   # issue 10's example: r1 and r2 each submit 6 on 3 idle robots
    ("unloaded", 5, 15, 0, 1),
    ("loaded", 5, 15, 1, 1),
    ("loaded", 5, 15, 2, 1),
    ("multi-origin", 5, 5, 0, 3),
]
FULL_CONFIGS: list[tuple[str, int, int, int, int]] = DEFAULT_CONFIGS + [
    ("unloaded", 2, 5, 0, 1),
    ("unloaded", 4, 20, 0, 1),
    ("unloaded", 5, 30, 0, 1),
    ("loaded", 5, 10, 3, 1),
    ("loaded", 5, 20, 4, 1),
    ("multi-origin", 5, 4, 1, 5),
    ("multi-origin", 4, 6, 1, 2),
]
SPACING = 0.05
#: a distribution whose model makespan is within this of the simulator's is as good
AS_GOOD = 0.01


class SweepCase(msgspec.Struct, kw_only=True):
    experiment: str
    robots: int
    programs: int
    loaded: int
    origins: int
    #: testbed: seconds from the first submission to the last result, and programs per robot (r1 first)
    makespan: float
    distribution: list[int]
    #: simulator, same configuration: median makespan over seeds, and each seed's distribution
    sim_makespan: float
    sim_distributions: list[list[int]]
    ratio: float
    #: CPU seconds of a work unit in the workers during the run, and when the speed was measured
    unit_cpu: float
    calibration: float
    corrected_ratio: float
    completed: int
    failed: int
    #: the host's 1-minute load average at the end (2 cores; the robots need ``quota * robots``)
    host_load: float
    #: the least share of the CPU it was due (its quota, times its busy emulated cores by the
    #: model) that a robot running programs got from the host, and the ratio with the simulator
    #: also scaled by it (capped at 1): what is left when the host's starvation is taken out
    cpu_obtained: float = 1.0
    starved_ratio: float = 0.0
    #: the model's makespan of the testbed's distribution and of the simulator's first
    #: (``shared_makespan``); whether the testbed's is one of the simulator's, or as good
    model_testbed: float = 0.0
    model_sim: float = 0.0
    same: bool = False
    as_good: bool = False
    #: robot -> the speed in its latest report just before the burst: what placement went by
    speeds: dict[str, float] = {}


class TestbedSweepReport(msgspec.Struct, kw_only=True):
    __test__ = False
    cores: int
    quota: float
    speed: float
    work: float
    seeds: int
    cases: list[SweepCase]
    mean_abs_ratio_error: float
    mean_abs_corrected_error: float
    wall_seconds: float = 0.0
    mean_abs_starved_error: float = 0.0
    #: True: every node was handed ``speed`` (an ablation); False: each
    #: measured itself, as on a robot, and said ``node_speeds``
    told_speed: bool = False
    #: team size -> robot -> the speed its node reported before the first configuration
    node_speeds: dict[str, dict[str, float]] = {}


def sim_scenario(robots: int, programs: int, loaded: int, origins: int, *, cores: int, speed: float, work: float,
                 stress: int = 8, worker_nice: int = 10, period: float = 1.0, seed: int = 0) -> Scenario:
    """The simulator's version of one testbed configuration (robot names as the testbed's)."""
    team = [RobotSpec(name=f"r{i}", cores=cores, speed=speed, background=stress if i > robots - loaded else 0,
                      worker_nice=worker_nice) for i in range(1, robots + 1)]
    progs = [ProgramSpec(program="burn", count=programs, work=work, payload=200, result=200, origin=f"r{o}",
                         spacing=SPACING, jitter=0.0) for o in range(1, origins + 1)]
    return Scenario(name=f"testbed-{robots}r-{origins}x{programs}p-{loaded}l", seed=seed, robots=team,
                    programs=progs, publisher=PublisherSpec(period=period, window=1.0), config=RampsConfig())


def shared_makespan(dist: Sequence[int], busy: Sequence[int], *, cores: int, speed: float, work: float,
                   worker_nice: int = 10) -> float:
    """Seconds until the last of ``dist[i]`` identical programs of ``work`` units
    ends on robot i, all started at once, sharing its ``cores`` (of ``speed``)
    with ``busy[i]`` processes at nice 0 by weighted processor sharing."""
    weight = nice_weight(worker_nice)
    return max((work / (speed * program_share(cores, n, b, weight)) for n, b in zip(dist, busy) if n), default=0.0)


def simulate_config(robots: int, programs: int, loaded: int, origins: int, *, cores: int, speed: float,
                    work: float, seeds: int = 3, policy: str = "ramps") -> tuple[float, list[list[int]]]:
    names = [f"r{i}" for i in range(1, robots + 1)]
    spans, dists = [], []
    for s in range(seeds):
        res = simulate(sim_scenario(robots, programs, loaded, origins, cores=cores, speed=speed, work=work,
                                    seed=1000 + s), policy=policy)
        if res.lost or res.completed != programs * origins:
            raise RuntimeError(f"the simulator lost programs in {res.scenario} seed {res.seed}")
        spans.append(res.makespan)
        dists.append([res.distribution.get(n, 0) for n in names])
    return statistics.median(spans), dists


def _workers_cpu(tb, seen: dict[str, dict[int, tuple[str, float]]]) -> None:
    """Add every robot's processes' CPU seconds so far to ``seen`` (robot -> pid -> (kind, seconds))."""
    from ramps.lab.fidelity import merge_cpu, robot_cpu

    for r in tb.names:
        merge_cpu(seen.setdefault(r, {}), robot_cpu(tb, r))


class _Burst(msgspec.Struct, kw_only=True):
    makespan: float
    distribution: list[int]
    completed: int
    failed: int
    #: CPU seconds of the programs' workers
    spent: float
    #: the least share of its due CPU any robot with programs obtained (1.0: all it should)
    obtained: float


def _usage(tb, robot: str) -> float:
    from ramps.runtime.measure import cgroup_usage

    dirs = [Path(d) for d in tb.robots[robot]["cgroup"]]
    return cgroup_usage(dirs[0], dirs[1] if len(dirs) > 1 else None)


def _run_on_testbed(tb, clients: dict, programs: int, origins: int, work: float, timeout: float, *,
                    cores: int, busy: dict[str, int]) -> _Burst:
    """One burst on a running testbed. Besides the makespan and distribution, how much of
    the CPU it was due each robot got while it ran programs: ``quota * min(1, (programs +
    busy) / cores)`` host cores by the model, against its cgroup's usage from the burst's
    start to its last program's end (a host busy with other work gives the robots less)."""
    before: dict[str, dict[int, tuple[str, float]]] = {}
    _workers_cpu(tb, before)
    seen = {r: dict(v) for r, v in before.items()}
    u0 = {r: _usage(tb, r) for r in tb.names}
    futures = []
    t0 = time.monotonic()
    for i in range(programs):  # the origins submit at the same moments, each its own program in turn
        for o in range(1, origins + 1):
            futures.append(clients[f"r{o}"].options(work=work).submit("burn", units=work))
        time.sleep(max(0.0, t0 + (i + 1) * SPACING - time.monotonic()))
    ends: list[float] = []
    for f in futures:
        f.add_done_callback(lambda _f: ends.append(time.monotonic()))
    last: dict[str, tuple[float, float]] = {}  # robot -> (time, usage) while it still ran a program
    deadline = time.monotonic() + timeout
    while not all(f.done() for f in futures) and time.monotonic() < deadline:
        _workers_cpu(tb, seen)
        now = time.monotonic()
        for r in {f.host for f in futures if not f.done() and f.host in tb.robots}:
            last[r] = (now, _usage(tb, r))
        time.sleep(0.2)
    _workers_cpu(tb, seen)
    ok = [f for f in futures if f.done() and f.exception() is None]
    for f in futures:
        if not f.done():
            f.cancel()
    dist = [sum(1 for f in ok if f.host == r) for r in tb.names]
    shares = []
    for r, k in zip(tb.names, dist):
        if k and r in last and last[r][0] - t0 > 1.0:
            due = tb.quota * min(1.0, (k + busy.get(r, 0)) / cores)
            shares.append((last[r][1] - u0[r]) / (last[r][0] - t0) / due)
    spent = sum(secs - before.get(r, {}).get(pid, (kind, 0.0))[1]
                for r, procs in seen.items() for pid, (kind, secs) in procs.items() if kind == "worker")
    return _Burst(makespan=(max(ends) - t0) if ends else float("nan"), distribution=dist, completed=len(ok),
                  failed=len(futures) - len(ok), spent=spent, obtained=min(shares, default=1.0))


def _case(config: tuple[str, int, int, int, int], b: _Burst, sim: float, sim_dists: list[list[int]],
          speeds: dict[str, float], *, busy: dict[str, int], names: Sequence[str], cores: int, speed: float,
          work: float, calibration: float) -> SweepCase:
    """A configuration's burst ``b`` on the testbed beside the simulator's
    median makespan ``sim`` and distributions ``sim_dists``."""
    exp, n, k, loaded, origins = config
    span, dist, done = b.makespan, b.distribution, b.completed
    unit = b.spent / max(done * work, 1e-9) if done else calibration
    corrected = sim * unit / calibration
    obtained = min(1.0, b.obtained)  # more than its due is not a correction
    loads = [busy.get(r, 0) for r in names]
    model_tb, model_sim = (shared_makespan(d, loads, cores=cores, speed=speed, work=work) for d in (dist, sim_dists[0]))
    return SweepCase(experiment=exp, robots=n, programs=k, loaded=loaded, origins=origins,
                     makespan=round(span, 2), distribution=dist, sim_makespan=round(sim, 2),
                     sim_distributions=sim_dists, ratio=round(span / sim, 3),
                     unit_cpu=round(unit, 3), calibration=round(calibration, 3),
                     corrected_ratio=round(span / corrected, 3), completed=done, failed=b.failed,
                     host_load=round(os.getloadavg()[0], 2), cpu_obtained=round(b.obtained, 3),
                     starved_ratio=round(span / (corrected / obtained), 3),
                     model_testbed=round(model_tb, 2), model_sim=round(model_sim, 2),
                     same=dist in sim_dists, as_good=model_tb <= model_sim * (1 + AS_GOOD), speeds=speeds)


def _wait_idle(obs, timeout: float = 30.0) -> None:
    """Until no robot reports a program running (the previous configuration's stragglers)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if not any(row.get("running") for row in obs.view()):
            return
        time.sleep(0.5)


def run_testbed_sweep(configs: Sequence[tuple[str, int, int, int, int]] | None = None, *, cores: int = 4,
                      quota: float = 0.2, work: float = 0.3, seeds: int = 3, stress: int = 8,
                      timeout: float = 300.0, keep_logs: Path | None = None, told_speed: bool = False,
                      log: Callable[[str], None] | None = None) -> TestbedSweepReport:
    """Every configuration on real processes and in the simulator (module docstring);
    with ``keep_logs``, every node's log and decision trace go to ``keep_logs/sweep-<robots>``.
    The nodes measure their own speeds, as on robots; ``told_speed`` hands each the speed measured
    here before the start instead (an ablation). The simulator runs at that speed either way: the
    true configuration."""
    from ramps.testbed import Testbed
    from ramps.testbed.bed import watch_team
    from ramps.lab.experiments import SETTLE, _keep, identical_speed

    log = log or (lambda _m: None)
    configs = list(configs or DEFAULT_CONFIGS)
    for exp, n, k, loaded, origins in configs:
        if exp not in EXPERIMENTS or not (1 <= origins <= n) or not (0 <= loaded < n) or k < 1:
            raise ValueError(f"bad configuration {(exp, n, k, loaded, origins)}: experiment one of "
                             f"{', '.join(EXPERIMENTS)}, 1 <= origins <= robots, 0 <= loaded < robots, programs >= 1")
    started = time.monotonic()
    speed = identical_speed(1, cores, quota)
    calibration = quota / (cores * speed)  # CPU seconds of a unit when the speed was measured
    log(f"one emulated core runs {speed:.4f} units/s ({calibration:.2f} CPU s a unit); {len(configs)} configurations")
    out: list[SweepCase] = []
    node_speeds: dict[str, dict[str, float]] = {}
    for size in sorted({c[1] for c in configs}):
        group = [c for c in configs if c[1] == size]
        with Testbed(size, cores=cores, quota=quota, speed=speed if told_speed else None) as tb, \
                watch_team(tb) as obs:
            clients = {f"r{o}": tb.client(f"r{o}", timeout=30.0) for o in range(1, max(c[4] for c in group) + 1)}
            try:
                node_speeds[str(size)] = reported_speeds(obs, size)
                log(f"  {size} robots: " + ("told " if told_speed else "measured themselves ")
                    + " ".join(f"{r} {v:.4f}" for r, v in node_speeds[str(size)].items())
                    + f" (spread {spread(node_speeds[str(size)]):.3f})")
                for exp, n, k, loaded, origins in group:
                    for i in range(n - loaded + 1, n + 1):
                        tb.add_load(f"r{i}", stress)
                    time.sleep(SETTLE)  # the load is adopted, capped and reported
                    sim, sim_dists = simulate_config(n, k, loaded, origins, cores=cores, speed=speed, work=work,
                                                     seeds=seeds)
                    busy = {f"r{i}": stress for i in range(n - loaded + 1, n + 1)}
                    speeds = reported_speeds(obs, n)
                    b = _run_on_testbed(tb, clients, k, origins, work, timeout, cores=cores, busy=busy)
                    case = _case((exp, n, k, loaded, origins), b, sim, sim_dists, speeds, busy=busy, names=tb.names,
                                 cores=cores, speed=speed, work=work, calibration=calibration)
                    span, dist, unit = case.makespan, case.distribution, case.unit_cpu
                    log(f"  {exp:12s} {n} robots, {origins} x {k} programs, {loaded} loaded: testbed {span:.1f} s "
                        f"{dist}, simulator {sim:.1f} s {sim_dists[0]}: ratio {case.ratio:.2f}, corrected "
                        f"{case.corrected_ratio:.2f} (a unit cost {unit:.2f} CPU s, calibration {calibration:.2f}), "
                        f"{case.starved_ratio:.2f} with the CPU the host gave (the least fed robot got "
                        f"{b.obtained:.0%} of its due); host load {case.host_load}; speeds before it "
                        f"{min(speeds.values()):.4f}-{max(speeds.values()):.4f} (spread {spread(speeds):.3f})")
                    out.append(case)
                    for i in range(n - loaded + 1, n + 1):
                        tb.remove_load(f"r{i}")
                    _wait_idle(obs)
            finally:
                for c in clients.values():
                    c.close()
                if keep_logs is not None:
                    _keep(tb, Path(keep_logs) / f"sweep-{size}")
    good = [c for c in out if c.completed]
    return TestbedSweepReport(
        cores=cores, quota=quota, speed=speed, work=work, seeds=seeds, cases=out, told_speed=told_speed,
        node_speeds=node_speeds,
        mean_abs_ratio_error=round(statistics.fmean(abs(c.ratio - 1) for c in good), 3) if good else 0.0,
        mean_abs_corrected_error=round(statistics.fmean(abs(c.corrected_ratio - 1) for c in good), 3) if good else 0.0,
        mean_abs_starved_error=round(statistics.fmean(abs(c.starved_ratio - 1) for c in good), 3) if good else 0.0,
        wall_seconds=round(time.monotonic() - started, 1))


def format_report(rep: TestbedSweepReport) -> str:
    told = (f"every node told {rep.speed:.4f}" if rep.told_speed else "nodes measured themselves: "
            + "; ".join(f"{n} robots {min(v.values(), default=0):.4f}-{max(v.values(), default=0):.4f} "
                        f"(spread {spread(v):.3f})" for n, v in rep.node_speeds.items()))
    lines = [(f"robots of {rep.cores} cores on {rep.quota:g} host cores, programs of {rep.work:g} units "
              f"({rep.work / rep.speed:.1f} s alone on an emulated core at {rep.speed:.4f}, measured here "
              f"before the start), simulator median of {rep.seeds} seeds"), told,
             (f"{'experiment':12s} {'robots':>6s} {'origins x programs':>18s} {'loaded':>6s} {'testbed s':>9s} "
              f"{'simulator s':>11s} {'ratio':>6s} {'corrected':>9s} {'CPU got':>7s} {'starved':>7s}  "
              "testbed / simulator distribution")]
    for c in rep.cases:
        lines.append(f"{c.experiment:12s} {c.robots:6d} {f'{c.origins} x {c.programs}':>18s} {c.loaded:6d} "
                     f"{c.makespan:9.1f} {c.sim_makespan:11.1f} {c.ratio:6.2f} {c.corrected_ratio:9.2f} "
                     f"{c.cpu_obtained:7.0%} {c.starved_ratio:7.2f}  "
                     f"{'-'.join(map(str, c.distribution))} / {'-'.join(map(str, c.sim_distributions[0]))}"
                     f" {'same' if c.same else 'as good' if c.as_good else 'worse'}"
                     + (f"  ({c.failed} failed)" if c.failed else ""))
    lines.append(f"mean |ratio - 1|: {rep.mean_abs_ratio_error:.1%}, corrected for the host's speed "
                 f"{rep.mean_abs_corrected_error:.1%}, and for the CPU the host gave the robots "
                 f"{rep.mean_abs_starved_error:.1%}; {rep.wall_seconds:.0f} s")
    lines.append("CPU got: the least share of its due CPU a robot running programs obtained from the host; "
                 "starved: the ratio with the simulator scaled by the host's speed and by that share; same: the "
                 "testbed's distribution is one of the simulator's seeds', as good: the model ends it as soon "
                 f"(within {AS_GOOD:.0%}: programs on cores of their own), worse: later")
    return "\n".join(lines)
