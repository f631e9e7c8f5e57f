"""``ramps demo``: the paper's scenario on a real team on this machine.

How this works: a ``LocalTeam`` of real node processes (default 5). Where
root and cpu cgroups are available, each robot is its own cgroup with an
equal share of this host's cores, so the five robots really are five small
computers ("emulated robots"); otherwise they share the host ("shared
host"), and speedups are bounded by its cores. Robot 1 then submits the
paper's workload (15 route-planning programs) three times in the same
session: placed by ramps, by round robin, and on robot 1 alone. A loaded
robot (``--loaded``) runs 8 busy processes inside its own cgroup; a killed
robot (``--kill``) is SIGKILLed mid-run and its programs are re-placed.
"""

from __future__ import annotations

import os
import time
from collections import Counter
from pathlib import Path
from typing import Callable

import msgspec

from ramps.runtime.localteam import cgroup_mode
from ramps.testing import LocalTeam


class PhaseResult(msgspec.Struct, kw_only=True):
    name: str
    makespan: float
    distribution: dict[str, int]
    completed: int
    failed: int
    replaced: int
    errors: list[str] = []


class DemoReport(msgspec.Struct, kw_only=True):
    mode: str
    robots: list[str]
    robot_cores: float
    programs: int
    program: str
    arguments: dict
    loaded: list[str]
    killed: str | None
    phases: list[PhaseResult]
    speedup_vs_single: float
    ratio_to_round_robin: float
    wall_seconds: float
    #: the HTML report of the ramps phase (ramps.observe.report), and the nodes' trace it was drawn from
    report: str = ""
    trace: str = ""


#: the demo's instance: ~1.4 CPU s per program on the development machine, so
#: 15 of them take ~50 s on one emulated robot and the whole demo ~1.5 min
DEMO_ROUTE = {"width": 20, "height": 12, "picks": 14, "capacity": 4, "seed": 1}


def route_calls(args: dict, n: int) -> list[dict]:
    """The paper's scenario: the robot meets an obstruction and explores the
    same order from ``n`` different start cells nearest to where it stands."""
    from ramps.programs.route import bfs, make_order, make_warehouse

    wh = make_warehouse(args.get("width", 20), args.get("height", 12), seed=args.get("seed", 0))
    order = make_order(wh, args.get("picks", 8), args.get("seed", 0))
    dist, _ = bfs(wh, order.start)
    near = sorted(dist, key=lambda cell: (dist[cell], cell))[:n]
    return [dict(args, start=list(cell)) for cell in near]


def _run_phase(name: str, team, calls: list[dict], *, program: str, options: dict,
               on_progress: Callable[[str, int, int, Counter], None] | None,
               during: Callable[[float], None] | None = None) -> PhaseResult:
    t0 = time.perf_counter()
    futs = [team.options(**options).submit(program, **c) for c in calls]
    dist: Counter = Counter()
    failed, errors, replaced = 0, [], 0
    pending = set(range(len(futs)))
    while pending:
        if during is not None:
            during(time.perf_counter() - t0)
        for i in list(pending):
            f = futs[i]
            if f.done():
                pending.discard(i)
                if f.exception() is None:
                    dist[f.host] += 1
                    replaced += 1 if getattr(f, "attempts", 1) > 1 else 0
                else:
                    failed += 1
                    errors.append(str(f.exception())[:200])
        if on_progress:
            on_progress(name, len(futs) - len(pending), len(futs), dist)
        time.sleep(0.05)
    return PhaseResult(name=name, makespan=time.perf_counter() - t0, distribution=dict(dist),
                       completed=sum(dist.values()), failed=failed, replaced=replaced, errors=errors)


def run_demo(*, robots: int = 5, programs: int = 15, program: str = "route_plan", arguments: dict | None = None,
             loaded: list[str] | None = None, kill: str | None = None, kill_at: float = 3.0,
             emulate: bool | None = None,
             on_progress: Callable[[str, int, int, Counter], None] | None = None,
             on_phase: Callable[[str], None] | None = None, report: str | None = None) -> DemoReport:
    """``report``: where to save an HTML report of the ramps phase (its
    nodes' trace is kept beside it, ``<name>.trace.jsonl``); None: none."""
    started = time.perf_counter()
    host_cores, quota, mode = _emulation(robots, emulate)
    loaded = list(loaded or [])
    args = dict(arguments or {})
    calls = route_calls(args, programs) if program == "route_plan" else [dict(args) for _ in range(programs)]
    names = [f"r{i}" for i in range(1, robots + 1)]
    _check_robots(names, loaded, kill)
    phases = []
    windows: dict[str, tuple[float, float]] = {}  # phase -> Unix times, to cut its part of the trace
    trace = _fresh_trace(report)
    env = dict(os.environ, RAMPS_TRACE=trace) if trace else None  # every node appends its decisions
    with LocalTeam(names, cpu_quota=quota, env=env) as team:
        for name in loaded:
            team.add_load(name, 8)
        client = team.client("r1")
        try:
            time.sleep(2.5)  # every load server hears every robot, loaded ones included
            # warm-up, not measured: each robot's workers load the solver once,
            # so no placement pays a first-import cost the others do not. One
            # call of the measured ones per robot: the origin learns work and
            # speeds from these runs, and smaller instances under the same name
            # and declaration would teach it a program 4-8x smaller than the
            # one it then places
            if program == "route_plan":
                warm = [client.options(policy="round_robin").submit(program, **c) for c in calls[:robots]]
                for f in warm:
                    f.result(timeout=120)
            killed: list[str] = []

            def during(elapsed: float) -> None:
                if kill and not killed and elapsed >= kill_at:
                    team.kill_node(kill)
                    killed.append(kill)

            for title, opts in (("ramps", {}), ("round robin", {"policy": "round_robin"}),
                                ("single robot (r1)", {"local_only": True})):
                if on_phase:
                    on_phase(title)
                w0 = time.time()
                phases.append(_run_phase(title, client, calls, program=program, options=opts,
                                         on_progress=on_progress, during=during if title == "ramps" else None))
                windows[title] = (w0, time.time())
                if killed and title == "ramps":
                    team.start_node(killed[0])  # back for the baselines, so they run on the same team
                    time.sleep(2.5)
        finally:
            client.close()
    ramps_t, rr_t, single_t = (p.makespan for p in phases)
    saved = ""
    if report and trace:  # trace: set whenever report is
        what = (f"{programs} x {program} from r1 placed by ramps on {robots} robots"
                + (f", {kill} killed at {kill_at:g} s" if kill else "") + (f", loaded: {', '.join(loaded)}" if loaded
                                                                           else ""))
        saved = _save_report(report, trace, what, windows["ramps"])
    return DemoReport(mode=mode, robots=names, robot_cores=quota or host_cores, programs=programs, program=program,
                      arguments=args, loaded=loaded, killed=kill, phases=phases,
                      speedup_vs_single=single_t / ramps_t, ratio_to_round_robin=ramps_t / rr_t,
                      wall_seconds=time.perf_counter() - started, report=saved, trace=trace or "")


def _emulation(robots: int, emulate: bool | None) -> tuple[int, float | None, str]:
    """(host cores, each robot's cgroup quota or None, the mode in words): emulated robots
    when asked, or by default where cpu cgroups can be written."""
    host_cores = len(os.sched_getaffinity(0))
    can_emulate = cgroup_mode() is not None
    if emulate and not can_emulate:
        raise PermissionError("emulated robots need root and writable cpu cgroups; run with --shared")
    emulate = can_emulate if emulate is None else emulate
    quota = host_cores / robots if emulate else None
    mode = (f"emulated robots: each node in its own cpu cgroup of {quota:.2f} of a host core "
            f"({robots} robots on this {host_cores}-core host)" if emulate else
            f"shared host: {robots} nodes share this machine's {host_cores} cores (no cgroups: not root, or "
            "--shared); speedups are bounded by the host's cores")
    return host_cores, quota, mode


def _check_robots(names: list[str], loaded: list[str], kill: str | None) -> None:
    """The loaded and the killed robot are in the team, and the killed one is not the origin."""
    for name in loaded + ([kill] if kill else []):
        if name not in names:
            raise ValueError(f"no robot {name!r} in this team ({', '.join(names)})")
    if kill == names[0]:
        raise ValueError("the origin r1 cannot be killed: its programs would be nobody's concern (paper 3.3)")


def _fresh_trace(report: str | None) -> str | None:
    """An empty trace file beside ``report`` (absolute: the nodes run in their own directory)."""
    trace = str(Path(report).with_suffix(".trace.jsonl").resolve()) if report else None
    if trace:
        Path(trace).parent.mkdir(parents=True, exist_ok=True)
        Path(trace).write_text("")
    return trace


def _save_report(report: str, trace: str, what: str, window: tuple[float, float]) -> str:
    """The HTML report of the ramps phase, drawn from its part of the trace; where it was saved."""
    from ramps.observe.report import make_report, write_html

    rep = make_report([Path(trace)], title=f"ramps demo: {what}", window=window)
    return str(write_html(rep, Path(report)))
