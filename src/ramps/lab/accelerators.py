"""Emulated accelerators on real processes, beside the simulator: ``ramps testbed experiment accelerators``.

How this works: a fresh testbed of ``robots`` emulated robots of ``cores``
cores (``quota`` host cores each) per repeat; the last ``accelerated`` of
them also offer an emulated accelerator, ``cuda:SLOTS:SPEED:emulated``
(``Testbed(robot_config=...)``; the others ``none``): slot locks that
programs hold for their work's time (``ramps.runtime.accelerators``). The
first ``origins`` robots each submit ``gpu`` GPU-class calls and ``cpu``
CPU calls, interleaved, ``SPACING`` apart, all from the same moment:

* GPU-class: ``burn_accel(units, accel_units)``: ``seconds`` alone on an
  emulated core, ``speedup`` times less on a slot of the accelerator;
* CPU: ``burn(units)``: ``seconds`` alone on an emulated core.

Measured: where each call ran (which robot; on its accelerator or a CPU),
from submission to result, and the makespan. Beside it, the simulator's
makespan and distribution for the same configuration (``simulate_case``:
the same robots and accelerators, the speed measured here before the start
as the robots' true one and each node's reported speed as what it believes,
the same calls at the same moments, the nodes' report period; median of
``seeds`` seeds), and ratio = testbed / simulator. ``corrected_ratio``
takes the host's drift out as ``ramps.lab.late_load`` does: the CPU
calls' median time on the testbed over the simulator's, the simulator run
again with robots that much slower.
"""

from __future__ import annotations

import os
import statistics
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import msgspec

from ramps.core.config import RampsConfig
from ramps.sim.engine import simulate
from ramps.sim.scenario import ProgramSpec, PublisherSpec, RobotSpec, Scenario

SPACING = 0.05
KIND = "cuda"
#: where a call ran: its robot's accelerator, a CPU for a GPU-class call, a CPU for a CPU call
PLACES = ("gpu on accelerator", "gpu on cpu", "cpu")


class Call(msgspec.Struct, kw_only=True, array_like=True):
    origin: str
    kind: str  # "gpu" or "cpu"
    host: str
    on: str  # "cuda:0" or "cpu"
    #: seconds from the first submission to its submission and to its result
    submitted: float
    ended: float
    #: seconds it held the emulated accelerator's slot, waits for it included (None: on a CPU)
    wall: float | None = None


class AccelRepeat(msgspec.Struct, kw_only=True):
    repeat: int
    #: the host's 1-minute load average when it started (2 cores here)
    host_load: float
    #: robot -> the speed its node reported before the burst
    node_speeds: dict[str, float]
    #: testbed: first submission to last result, and robot -> calls per PLACES
    makespan: float
    distribution: dict[str, list[int]]
    completed: int
    failed: int
    #: simulator, same configuration: median makespan over its seeds, that seed's distribution
    sim_makespan: float
    sim_distribution: dict[str, list[int]]
    ratio: float
    #: the CPU calls' median time, testbed over simulator, and the simulator with robots that much slower
    host_factor: float = 1.0
    sim_corrected: float = 0.0
    corrected_ratio: float = 0.0
    calls: list[Call] = []


class AccelReport(msgspec.Struct, kw_only=True):
    robots: int
    cores: int
    quota: float
    #: work units a second of one emulated core, measured here before the first repeat
    speed: float
    accelerated: list[str]
    accelerator: str
    origins: int
    gpu: int
    cpu: int
    seconds: float
    speedup: float
    units: float
    accel_units: float
    seeds: int
    repeats: list[AccelRepeat]
    wall_seconds: float = 0.0


def interleave(gpu: int, cpu: int) -> list[str]:
    """One origin's submission order: ``gpu`` "gpu" and ``cpu`` "cpu" spread evenly."""
    marks = [((i + 0.5) / gpu, 0, "gpu") for i in range(gpu)] + [((j + 0.5) / cpu, 1, "cpu") for j in range(cpu)]
    return [k for _, _, k in sorted(marks)]


def _place(kind: str, on: str) -> int:
    return 2 if kind == "cpu" else (1 if on == "cpu" else 0)


def distribution(calls: list[Call], names: list[str]) -> dict[str, list[int]]:
    """robot -> [GPU-class calls on its accelerator, GPU-class calls on its CPU, CPU calls]."""
    out = {n: [0, 0, 0] for n in names}
    for c in calls:
        if c.host in out:
            out[c.host][_place(c.kind, c.on)] += 1
    return out


def sim_scenario(*, robots: int, cores: int, speed: float, accelerated: list[str], accelerator: str, origins: int,
                 gpu: int, cpu: int, units: float, accel_units: float, node_speeds: dict[str, float] | None = None,
                 seed: int = 0) -> Scenario:
    """The simulator's version of one repeat: robots of true speed ``speed`` that believe
    ``node_speeds`` (their nodes' reports), the same calls at the same moments."""
    node_speeds = node_speeds or {}
    team = [RobotSpec(name=f"r{i}", cores=cores, speed=speed, measured_speed=node_speeds.get(f"r{i}") or None,
                      accelerators=[accelerator] if f"r{i}" in accelerated else [], worker_nice=10)
            for i in range(1, robots + 1)]
    progs = []
    for o in range(1, origins + 1):
        for i, kind in enumerate(interleave(gpu, cpu)):
            if kind == "gpu":
                progs.append(ProgramSpec(program="burn_accel", work=units, accelerator=KIND, accelerator_work=accel_units,
                                         payload=60, result=100, origin=f"r{o}", at=i * SPACING))
            else:
                progs.append(ProgramSpec(program="burn", work=units, payload=50, result=100, origin=f"r{o}",
                                         at=i * SPACING))
    return Scenario(name=f"testbed-accel-{robots}r-{origins}x{gpu}g{cpu}c", seed=seed, robots=team, programs=progs,
                    publisher=PublisherSpec(period=1.0, window=1.0), config=RampsConfig())


def simulate_case(seeds: int = 3, **kw: Any) -> tuple[float, list[Call]]:
    """The simulator's median makespan over ``seeds`` seeds of ``sim_scenario(**kw)``, and that
    seed's calls (as the testbed's: times from the first submission)."""
    order = interleave(kw["gpu"], kw["cpu"])
    runs = []
    for s in range(seeds):
        res = simulate(sim_scenario(**kw, seed=1000 + s))
        if res.lost or res.duplicated or res.completed != kw["origins"] * len(order):
            raise RuntimeError(f"the simulator lost or duplicated programs in {res.scenario} seed {res.seed}")
        first = min(p.submitted_at for p in res.programs)
        calls = []
        for p in res.programs:
            kind = order[round((p.submitted_at - first) / SPACING)]
            on = f"{KIND}:0" if kind == "gpu" and p.host in kw["accelerated"] else "cpu"
            calls.append(Call(origin=p.origin, kind=kind, host=p.host or "", on=on,
                              submitted=round(p.submitted_at - first, 3),
                              ended=round((p.delivered_at or first) - first, 3)))
        runs.append((res.makespan, calls))
    runs.sort(key=lambda r: r[0])
    return runs[len(runs) // 2]


def _median_cpu_time(calls: list[Call]) -> float:
    times = [c.ended - c.submitted for c in calls if c.kind == "cpu"]
    return statistics.median(times) if times else 0.0


def run_testbed_accelerators(*, robots: int = 4, cores: int = 2, quota: float = 0.25, accelerated: int = 1,
                             slots: int = 1, slot_speed: float = 20.0, origins: int = 2, gpu: int = 3, cpu: int = 3,
                             seconds: float = 12.0, speedup: float = 10.0, repeats: int = 3, seeds: int = 3,
                             timeout: float = 300.0, keep_logs: Path | None = None,
                             log: Callable[[str], None] | None = None) -> AccelReport:
    """``repeats`` runs of the experiment (module docstring), each on a fresh testbed."""
    from ramps.lab.experiments import identical_speed

    log = log or (lambda _m: None)
    if not (1 <= accelerated < robots and 1 <= origins <= robots - accelerated and gpu + cpu >= 1
            and speedup > 0 and slots >= 1 and slot_speed > 0):
        raise ValueError("need 1 <= accelerated < robots, 1 <= origins <= robots - accelerated (the origins "
                         "offer no accelerator), gpu + cpu >= 1, speedup > 0, slots >= 1 and slot_speed > 0")
    started = time.monotonic()
    speed = identical_speed(1, cores, quota)
    units = round(seconds * speed, 4)
    accel_units = round(seconds / speedup * slot_speed, 4)
    names = [f"r{i}" for i in range(1, robots + 1)]
    accel = names[robots - accelerated:]
    text = f"{KIND}:{slots}:{slot_speed:g}"
    log(f"one emulated core runs {speed:.4f} units/s: calls of {units:g} units ({seconds:g} s alone on a core); "
        f"GPU-class ones {accel_units:g} units on a slot of {text} ({seconds / speedup:g} s) on {', '.join(accel)}")
    rep = AccelReport(robots=robots, cores=cores, quota=quota, speed=speed, accelerated=accel, accelerator=text,
                      origins=origins, gpu=gpu, cpu=cpu, seconds=seconds, speedup=speedup, units=units,
                      accel_units=accel_units, seeds=seeds, repeats=[])
    sim_kw = dict(robots=robots, cores=cores, accelerated=accel, accelerator=text, origins=origins, gpu=gpu,
                  cpu=cpu, units=units, accel_units=accel_units)
    for k in range(repeats):
        run = _one_repeat(k, speed=speed, quota=quota, sim_kw=sim_kw, seeds=seeds, timeout=timeout,
                          keep_logs=None if keep_logs is None else Path(keep_logs) / f"repeat-{k + 1}")
        log(f"  repeat {k + 1}: testbed {run.makespan:.1f} s, simulator {run.sim_makespan:.1f} s, ratio "
            f"{run.ratio:.3f} (corrected {run.corrected_ratio:.3f}, host {run.host_factor:.2f}x); "
            f"{_dist_text(run.distribution)} / {_dist_text(run.sim_distribution)}; host load {run.host_load:.2f}")
        rep.repeats.append(run)
    rep.wall_seconds = round(time.monotonic() - started, 1)
    return rep


def _one_repeat(k: int, *, speed: float, quota: float, sim_kw: dict[str, Any], seeds: int, timeout: float,
                keep_logs: Path | None) -> AccelRepeat:
    """One fresh testbed: the burst, then the simulator with the speeds its nodes reported."""
    from ramps.testbed import Testbed
    from ramps.testbed.bed import watch_team
    from ramps.lab.experiments import _keep
    from ramps.lab.speeds import reported_speeds

    robots, accel = sim_kw["robots"], sim_kw["accelerated"]
    names = [f"r{i}" for i in range(1, robots + 1)]
    load = os.getloadavg()[0]
    emulated = [f"{sim_kw['accelerator']}:emulated"]
    with Testbed(robots, cores=sim_kw["cores"], quota=quota, config={"accelerators": ["none"]},
                 robot_config={r: {"accelerators": emulated} for r in accel}) as tb:
        clients = {f"r{o}": tb.client(f"r{o}", timeout=30.0) for o in range(1, sim_kw["origins"] + 1)}
        try:
            with watch_team(tb) as obs:
                node_speeds = reported_speeds(obs, robots)
            for c in clients.values():
                _wait_for_accelerators(c, accel)
            calls, failed, span = _burst(clients, sim_kw, timeout)
        finally:
            for c in clients.values():
                c.close()
            if keep_logs is not None:
                _keep(tb, keep_logs)
    sim, sim_calls = simulate_case(seeds, speed=speed, node_speeds=node_speeds, **sim_kw)
    factor = _median_cpu_time(calls) / _median_cpu_time(sim_calls) if _median_cpu_time(sim_calls) > 0 else 1.0
    corrected = simulate_case(seeds, speed=speed / factor, node_speeds=node_speeds, **sim_kw)[0] \
        if factor > 0 else sim
    return AccelRepeat(repeat=k + 1, host_load=round(load, 2), node_speeds=node_speeds, makespan=round(span, 2),
                       distribution=distribution(calls, names), completed=len(calls), failed=failed,
                       sim_makespan=round(sim, 2), sim_distribution=distribution(sim_calls, names),
                       ratio=round(span / sim, 3), host_factor=round(factor, 3), sim_corrected=round(corrected, 2),
                       corrected_ratio=round(span / corrected, 3), calls=calls)


def _wait_for_accelerators(team: Any, accel: list[str], timeout: float = 20.0) -> None:
    """Until ``team``'s origin sees every robot of ``accel`` advertise its accelerator."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if set(accel) <= {r.robot for r in team.status().robots if r.accelerators}:
            return
        time.sleep(0.3)
    raise TimeoutError(f"the origin did not see {', '.join(accel)} advertise an accelerator within {timeout:g} s")


def _burst(clients: dict[str, Any], kw: dict[str, Any], timeout: float) -> tuple[list[Call], int, float]:
    """Every origin submits its calls, interleaved, ``SPACING`` apart; returns the calls that
    ended with a result, how many did not, and the makespan."""
    order = interleave(kw["gpu"], kw["cpu"])
    futures: list[tuple[str, str, float, Any]] = []
    ends: dict[int, float] = {}
    t0 = time.monotonic()
    for i, kind in enumerate(order):
        for origin, team in clients.items():
            at = time.monotonic() - t0
            if kind == "gpu":
                f = team.submit("burn_accel", units=kw["units"], accel_units=kw["accel_units"])
            else:
                f = team.options(work=kw["units"]).submit("burn", units=kw["units"])
            n = len(futures)
            f.add_done_callback(lambda _f, n=n: ends.setdefault(n, time.monotonic()))
            futures.append((origin, kind, at, f))
        time.sleep(max(0.0, t0 + (i + 1) * SPACING - time.monotonic()))
    deadline = t0 + timeout
    while not all(f.done() for *_, f in futures) and time.monotonic() < deadline:
        time.sleep(0.1)
    calls = []
    for n, (origin, kind, at, f) in enumerate(futures):
        if f.done() and not f.cancelled() and f.exception() is None and n in ends:
            got = f.result()
            calls.append(Call(origin=origin, kind=kind, host=f.host or "", on=str(got.get("on", "cpu")),
                              submitted=round(at, 3), ended=round(ends[n] - t0, 3), wall=got.get("wall")))
        elif not f.done():
            f.cancel()
    span = max((c.ended for c in calls), default=float("nan")) if len(calls) == len(futures) else float("nan")
    return calls, len(futures) - len(calls), span


def _dist_text(dist: dict[str, list[int]]) -> str:
    """``r1 0/0/2 r4 6/0/1``: per robot, GPU-class calls on its accelerator / on its CPU / CPU calls."""
    return " ".join(f"{r} {'/'.join(map(str, v))}" for r, v in dist.items())


def format_report(rep: AccelReport) -> str:
    lines = [(f"{rep.robots} robots of {rep.cores} cores on {rep.quota:g} host cores each ({rep.speed:.4f} units/s a "
              f"core); {', '.join(rep.accelerated)} also offer{'s' if len(rep.accelerated) == 1 else ''} an emulated "
              f"{rep.accelerator}; r1..r{rep.origins} each submit {rep.gpu} GPU-class calls ({rep.seconds:g} s on a "
              f"core, {rep.seconds / rep.speedup:g} s on a slot) and {rep.cpu} CPU calls ({rep.seconds:g} s), "
              f"interleaved; simulator median of {rep.seeds} seeds"),
             (f"{'repeat':>6s} {'load':>5s} {'testbed s':>9s} {'simulator s':>11s} {'ratio':>6s} {'host':>5s} "
              f"{'sim at host':>11s} {'ratio':>6s}  testbed / simulator: robot gpu-on-accelerator/gpu-on-cpu/cpu")]
    for r in rep.repeats:
        lines.append(f"{r.repeat:6d} {r.host_load:5.2f} {r.makespan:9.1f} {r.sim_makespan:11.1f} {r.ratio:6.3f} "
                     f"{r.host_factor:5.2f} {r.sim_corrected:11.1f} {r.corrected_ratio:6.3f}  "
                     f"{_dist_text(r.distribution)} / {_dist_text(r.sim_distribution)}"
                     + (f"  ({r.failed} failed)" if r.failed else ""))
    done = [r for r in rep.repeats if r.makespan == r.makespan]
    if done:
        lines.append(f"ratio = testbed / simulator: median {statistics.median(r.ratio for r in done):.3f}, worst "
                     f"{max(abs(r.ratio - 1) for r in done):.1%} off; corrected for the host's drift: median "
                     f"{statistics.median(r.corrected_ratio for r in done):.3f}, worst "
                     f"{max(abs(r.corrected_ratio - 1) for r in done):.1%} off; {rep.wall_seconds:.0f} s")
    lines.append("host = the CPU calls' median time on the testbed over the simulator's; sim at host = the "
                 "simulator with robots that much slower")
    return "\n".join(lines)


__all__ = ["AccelReport", "AccelRepeat", "Call", "format_report", "interleave", "run_testbed_accelerators",
           "sim_scenario", "simulate_case"]
