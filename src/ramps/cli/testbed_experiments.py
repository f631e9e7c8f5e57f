"""``ramps testbed experiment``: the paper's experiments on real processes.

    ramps testbed experiment faults  # the paper's Tables 5-10 on real processes
    ramps testbed experiment sweep   # Tables 3-4
    ramps testbed experiment peers   # ramps beside round robin, Ray and Dask
    ramps testbed experiment battery # a robot's battery drops below its reserve mid-run
    ramps testbed experiment accelerators  # GPU-class calls on emulated accelerators

Each command starts its own testbed, runs, and removes it; the work is done
by ``ramps.lab``, this module parses and prints (rules in
``ramps.cli.common``). ``ramps.cli.testbed`` mounts ``experiment_app`` as
``ramps testbed experiment``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import msgspec
import typer

from ramps.cli.common import (
    POLICY_HELP,
    DiscoveryOption,
    check_discovery,
    check_policy,
    command_group,
    emit,
    err,
    fail,
    fault_plans,
    save_json,
)


experiment_app = command_group("The paper's experiments on real processes (each run starts its own testbed).")


@experiment_app.command("faults")
def testbed_experiment_faults(
    mode: str = typer.Option("sequential", "--mode", "-m", help="sequential, simultaneous or all"),
    kind: str = typer.Option("crash", "--kind", "-k", help="crash, network, mixed or all"),
    runs: int = typer.Option(1, "--runs", min=1, help="runs of every plan"),
    gap: float = typer.Option(20.0, "--gap", min=4.0, help="seconds from the submit to the first failure and between failures (paper: 20)"),
    work: Optional[float] = typer.Option(None, "--work", help="work units per program (default 0.9 * gap: still running at the last snapshot)"),
    policy: str = typer.Option("ramps", "--policy", "-p", help=POLICY_HELP),
    lease_ms: Optional[int] = typer.Option(None, "--lease-ms", help="Zenoh lease of every node, ms (default: the node's)"),
    keep_logs: Optional[Path] = typer.Option(None, "--keep-logs", help="copy every node's log and decision trace here"),
    discovery: DiscoveryOption = "both",
    told_speed: bool = typer.Option(False, "--told-speed", help="ablation: hand every node the speed measured before the start (--speed) instead of letting each measure itself, as robots do"),
    as_json: bool = typer.Option(False, "--json", help="write the results as JSON to stdout"),
    out_file: Optional[Path] = typer.Option(None, "--out", help="also save the JSON here"),
) -> None:
    """The paper's failure experiments (Tables 5-10) on the testbed: 15 programs from r1 on five
    robots, then failures of r5, r4, r3, r2 (crash = SIGKILL, network = link down), with the same
    plans, tables and per-failure figures as `ramps sim paper --experiment faults`."""
    from functools import partial

    from ramps.errors import RampsError
    from ramps.experiments.faults import KINDS, plans, run_fault_experiment
    from ramps.experiments.report import print_fault_report
    from ramps.lab.experiments import run_plan

    check_policy(policy)
    modes, kinds = fault_plans(mode, kind, KINDS)
    total = sum(len(plans(m, k, first=gap, gap=gap)) for m in modes for k in kinds) * runs
    err.print(f"{total} testbed run(s); each takes {gap * 5:g}+ s plus the time the survivors need to finish")
    check_discovery(discovery)
    runner = partial(run_plan, told_speed=told_speed, work=work, lease_ms=lease_ms, keep_logs=keep_logs, discovery=discovery,
                     log=lambda m: err.print(m, highlight=False))
    reports = []
    try:
        for m in modes:
            for k in kinds:
                reports.append(run_fault_experiment(m, k, policy=policy, runs=runs, runner=runner, first=gap, gap=gap,
                                                    world="testbed"))
                if out_file is not None and len(modes) * len(kinds) > 1:  # a long run keeps what it has finished
                    save_json(msgspec.json.encode({"experiments": reports, "partial": True}), out_file)
    except (PermissionError, RampsError) as exc:
        fail(str(exc))
    except KeyboardInterrupt:
        if not reports:
            raise typer.Exit(130)
        err.print(f"interrupted: the {len(reports)} finished experiment(s) follow")
        emit(reports, print_fault_report, as_json=as_json, out_file=out_file)
        raise typer.Exit(130)
    emit(reports, print_fault_report, as_json=as_json, out_file=out_file)
    if any(r.summary["lost"] or r.summary["duplicated"] for r in reports):
        raise typer.Exit(1)


@experiment_app.command("sweep")
def testbed_experiment_sweep(
    experiment: str = typer.Option("all", "--experiment", "-e", help="unloaded (the paper's Table 3), loaded (Table 4), multi-origin (several robots submit at once) or all"),
    full: bool = typer.Option(False, "--full", help="13 configurations instead of 6 (about twice as long)"),
    quota: float = typer.Option(0.2, "--quota", min=0.05, max=4.0, help="host cores of each robot (5 robots of 0.2 take one of this host's cores)"),
    cores: int = typer.Option(4, "--cores", min=1, max=16, help="emulated cores of each robot"),
    work: float = typer.Option(0.3, "--work", min=0.05, max=10.0, help="work units of each program (0.3: about 9 s alone on an emulated core of 0.05 host cores)"),
    seeds: int = typer.Option(3, "--seeds", min=1, max=20, help="simulator runs per configuration (the median is compared)"),
    keep_logs: Path | None = typer.Option(None, "--keep-logs", help="copy every node's log and decision trace here (one folder per team size)"),
    told_speed: bool = typer.Option(False, "--told-speed", help="ablation: hand every node the speed measured before the start (--speed) instead of letting each measure itself, as robots do"),
    as_json: bool = typer.Option(False, "--json", help="write the report as JSON to stdout"),
    out_file: Optional[Path] = typer.Option(None, "--out", help="also save the JSON here"),
) -> None:
    """The paper's unloaded and loaded sweeps (Tables 3-4) and several-origins bursts on real node
    processes, each beside the simulator's makespan and distribution for the same configuration:
    the simulator's fidelity per configuration (ratio = testbed / simulator; corrected = with the
    simulator scaled by what a work unit cost the host during the run; starved = also by the least
    share of its due CPU a robot obtained from the host). The nodes measure their own speeds, as
    on robots (--told-speed hands them one, an ablation). About 2-4 minutes."""
    from ramps.errors import RampsError
    from ramps.lab.sweeps import DEFAULT_CONFIGS, EXPERIMENTS, FULL_CONFIGS, format_report, run_testbed_sweep

    if experiment not in EXPERIMENTS + ("all",):
        fail(f"unknown experiment {experiment!r}; choose {', '.join(EXPERIMENTS)} or all")
    configs = [c for c in (FULL_CONFIGS if full else DEFAULT_CONFIGS) if experiment in ("all", c[0])]
    err.print(f"{len(configs)} configuration(s) on the testbed and in the simulator ...")
    try:
        rep = run_testbed_sweep(configs, cores=cores, quota=quota, work=work, seeds=seeds, keep_logs=keep_logs,
                                told_speed=told_speed, log=lambda m: err.print(m, highlight=False))
    except (PermissionError, RampsError, RuntimeError, ValueError) as exc:
        fail(str(exc))
    emit([rep], lambda r, console: console.print(format_report(r), highlight=False), as_json=as_json,
         out_file=out_file)
    if any(c.failed for c in rep.cases):
        raise typer.Exit(1)


@experiment_app.command("slow-link")
def testbed_experiment_slow_link(
    rate: float = typer.Option(1.0, "--rate", min=0.01, max=1000.0, help="MB/s of the slowed robot's link (tbf; this kernel has no netem, so no added delay)"),
    payload: int = typer.Option(5_000_000, "--payload", min=1, max=8_000_000, help="bytes of parameters of each program (a client sends at most 8 MB less 64 KiB)"),
    units: float = typer.Option(0.3, "--units", min=0.01, max=10.0, help="work units of each program"),
    programs: int = typer.Option(6, "--programs", min=1, max=100, help="programs per run, submitted one after another"),
    told_speed: bool = typer.Option(False, "--told-speed", help="ablation: hand every node the speed measured before the start (--speed) instead of letting each measure itself, as robots do"),
    as_json: bool = typer.Option(False, "--json", help="write the report as JSON to stdout"),
    out_file: Path | None = typer.Option(None, "--out", help="also save the JSON here"),
    keep_logs: Path | None = typer.Option(None, "--keep-logs", help="copy the nodes' logs and decision traces here (one folder per run)"),
) -> None:
    """T_comm measured per teammate: r1 (loaded) places programs with large parameters on idle r2
    and r3, first with every link at full speed, then with r3's link slowed (tc tbf, both directions);
    prints r1's measured link to each teammate (what `ramps status` shows), how its estimate of r3's
    bandwidth converges, and where the programs ran. About 4 minutes (5 MB programs over a 1 MB/s link)."""
    from ramps.errors import RampsError
    from ramps.lab.slowlink import format_report, run_slow_link

    try:
        rep = run_slow_link(told_speed=told_speed, rate=rate * 1e6, payload=payload, units=units, programs=programs,
                            log=lambda m: err.print(m, highlight=False), keep_logs=keep_logs)
    except (PermissionError, RampsError, RuntimeError, TimeoutError) as exc:
        fail(str(exc))
    emit([rep], lambda r, console: console.print(format_report(r), highlight=False), as_json=as_json,
         out_file=out_file)


__import__("ramps.cli.sites", fromlist=["register"]).register(experiment_app)  # experiment sites
__import__("ramps.cli.split", fromlist=["register"]).register(experiment_app)  # experiment split


@experiment_app.command("relocation")
def testbed_experiment_relocation(
    robots: int = typer.Option(3, "--robots", min=2, max=10, help="emulated robots (r1 submits and gets busy)"),
    programs: int = typer.Option(8, "--programs", min=1, max=100, help="programs r1 submits at once"),
    seconds: float = typer.Option(30.0, "--seconds", min=5.0, max=600.0, help="each program's length alone on an emulated core"),
    load_at: float = typer.Option(6.0, "--load-at", min=0.5, help="seconds after the first submission when r1 gets busy"),
    busy: int = typer.Option(8, "--busy", min=1, max=64, help="busy processes r1's own software starts"),
    variant: Optional[list[str]] = typer.Option(None, "--variant", help="run only these (repeatable): relocation off, relocation, relocation + checkpoints"),
    told_speed: bool = typer.Option(False, "--told-speed", help="ablation: hand every node the speed measured before the start (--speed) instead of letting each measure itself, as robots do"),
    as_json: bool = typer.Option(False, "--json", help="write the report as JSON to stdout"),
    out_file: Optional[Path] = typer.Option(None, "--out", help="also save the JSON here"),
    keep_logs: Optional[Path] = typer.Option(None, "--keep-logs", help="copy every node's log and decision trace here"),
) -> None:
    """Relocation after placement on real processes, beside `ramps sim relocation`: r1 submits a
    burst on idle robots of 4 emulated cores and gets busy processes a few seconds later; runs
    relocation off, relocation (restart elsewhere) and relocation with checkpointing programs, each on
    a fresh testbed, and prints every makespan beside the simulator's and the hindsight optimum.
    About 4 minutes with the defaults."""
    from ramps.errors import RampsError
    from ramps.lab.late_load import VARIANTS, format_report, run_testbed_relocation

    if load_at >= seconds:
        fail(f"--load-at ({load_at:g}) must come before the programs end (--seconds {seconds:g})")
    chosen = tuple(variant) if variant else VARIANTS
    unknown = [v for v in chosen if v not in VARIANTS]
    if unknown:
        fail(f"unknown variant {unknown[0]!r}: choose from {', '.join(VARIANTS)}")
    try:
        rep = run_testbed_relocation(told_speed=told_speed, robots=robots, programs=programs, seconds=seconds, load_at=load_at, busy=busy,
                                     variants=chosen, keep_logs=keep_logs,
                                     log=lambda m: err.print(m, highlight=False))
    except (PermissionError, RampsError, RuntimeError, TimeoutError) as exc:
        fail(str(exc))
    emit([rep], lambda r, console: console.print(format_report(r), highlight=False), as_json=as_json,
         out_file=out_file)


@experiment_app.command("battery")
def testbed_experiment_battery(
    robots: int = typer.Option(3, "--robots", min=2, max=10, help="emulated robots (r1 submits)"),
    programs: int = typer.Option(6, "--programs", min=1, max=100, help="programs r1 submits at once"),
    seconds: float = typer.Option(12.0, "--seconds", min=2.0, max=600.0,
                                  help="each program's length alone on an emulated core"),
    drop_at: float = typer.Option(4.0, "--drop-at", min=0.5,
                                  help="seconds after the first submission when a host's battery drops to 10%"),
    as_json: bool = typer.Option(False, "--json", help="write the report as JSON to stdout"),
    out_file: Optional[Path] = typer.Option(None, "--out", help="also save the JSON here"),
    keep_logs: Optional[Path] = typer.Option(None, "--keep-logs", help="copy every node's log and decision trace here"),
) -> None:
    """A robot's battery drops below its reserve mid-run, on real processes: every node reads its
    battery from a file (--battery-file); r1 submits checkpointing programs, and the teammate that
    hosts the most of them gets 10% written into its file. Prints how long it took to hand them back
    (from the write to its decision, and to the last accepted elsewhere; it reads the file before each
    1 s load report) and checks every program's one result. About a minute."""
    from ramps.errors import RampsError
    from ramps.lab.battery import format_report, run_testbed_battery

    if drop_at >= seconds:
        fail(f"--drop-at ({drop_at:g}) must come before the programs end (--seconds {seconds:g})")
    try:
        rep = run_testbed_battery(robots=robots, programs=programs, seconds=seconds, drop_at=drop_at,
                                  keep_logs=keep_logs, log=lambda m: err.print(m, highlight=False))
    except (PermissionError, RampsError, RuntimeError, TimeoutError) as exc:
        fail(str(exc))
    emit([rep], lambda r, console: console.print(format_report(r), highlight=False), as_json=as_json,
         out_file=out_file)
    if rep.failed or rep.wrong or rep.on_low_after:
        raise typer.Exit(1)


@experiment_app.command("accelerators")
def testbed_experiment_accelerators(
    robots: int = typer.Option(4, "--robots", min=2, max=10, help="emulated robots"),
    accelerated: int = typer.Option(1, "--accelerated", min=1, max=9, help="the last N robots also offer an emulated accelerator"),
    slots: int = typer.Option(1, "--slots", min=1, max=8, help="slots of each accelerator"),
    slot_speed: float = typer.Option(20.0, "--slot-speed", min=0.1, max=1000.0, help="work units a second of one slot"),
    origins: int = typer.Option(2, "--origins", min=1, max=9, help="robots r1..rN submit (none of them accelerated)"),
    gpu: int = typer.Option(3, "--gpu", min=0, max=100, help="GPU-class calls (burn_accel) each origin submits"),
    cpu: int = typer.Option(3, "--cpu", min=0, max=100, help="CPU calls (burn) each origin submits"),
    seconds: float = typer.Option(12.0, "--seconds", min=1.0, max=600.0, help="each call alone on an emulated core"),
    speedup: float = typer.Option(10.0, "--speedup", min=0.1, max=1000.0, help="how many times sooner a GPU-class call ends on a slot"),
    repeats: int = typer.Option(3, "--repeats", min=1, max=20, help="runs, each on a fresh testbed"),
    seeds: int = typer.Option(3, "--seeds", min=1, max=20, help="simulator runs per repeat (the median is compared)"),
    as_json: bool = typer.Option(False, "--json", help="write the report as JSON to stdout"),
    out_file: Optional[Path] = typer.Option(None, "--out", help="also save the JSON here"),
    keep_logs: Optional[Path] = typer.Option(None, "--keep-logs", help="copy every node's log and decision trace here (repeat-N/)"),
) -> None:
    """Emulated accelerators on real processes, beside the simulator: the last robots offer an
    emulated GPU (slot locks, `--accelerator cuda:1:20:emulated`); the origins submit GPU-class calls
    (burn_accel, SPEEDUP times sooner on a slot) and CPU calls at once. Prints where each kind ran (on
    an accelerator or a CPU, per robot) and the makespan beside the simulator's for the same robots,
    speeds and calls. About 40 s a repeat."""
    from ramps.errors import RampsError
    from ramps.lab.accelerators import format_report, run_testbed_accelerators

    try:
        rep = run_testbed_accelerators(robots=robots, accelerated=accelerated, slots=slots, slot_speed=slot_speed,
                                       origins=origins, gpu=gpu, cpu=cpu, seconds=seconds, speedup=speedup,
                                       repeats=repeats, seeds=seeds, keep_logs=keep_logs,
                                       log=lambda m: err.print(m, highlight=False))
    except (PermissionError, RampsError, RuntimeError, TimeoutError, ValueError) as exc:
        fail(str(exc))
    emit([rep], lambda r, console: console.print(format_report(r), highlight=False, markup=False), as_json=as_json,
         out_file=out_file)
    if any(r.failed for r in rep.repeats):
        raise typer.Exit(1)


@experiment_app.command("speeds")
def testbed_experiment_speeds(
    starts: int = typer.Option(10, "--starts", min=1, max=100, help="fresh testbeds to start, one after another"),
    robots: int = typer.Option(5, "--robots", min=2, max=20, help="identical robots in each"),
    cores: int = typer.Option(4, "--cores", min=1, max=16, help="emulated cores of each robot"),
    quota: float = typer.Option(0.32, "--quota", min=0.05, max=4.0, help="host cores of each robot"),
    loaded: int = typer.Option(0, "--loaded", metavar="N", min=0, max=32, help="busy processes each robot's own software starts beside its node"),
    as_json: bool = typer.Option(False, "--json", help="write the report as JSON to stdout"),
    out_file: Optional[Path] = typer.Option(None, "--out", help="also save the JSON here"),
) -> None:
    """Do identical robots measure themselves alike? Starts a team of identical robots again and
    again, every node measuring its own speed (nothing handed in, as on real robots), and prints each
    node's boot speed and the speeds they report 2, 10 and 20 s later, with the spread (fastest over
    slowest) of each start. About 35 s per start."""
    from ramps.errors import RampsError
    from ramps.lab.speeds import run_speeds

    try:
        rep = run_speeds(starts=starts, robots=robots, cores=cores, quota=quota, loaded=loaded,
                         log=lambda m: err.print(m, highlight=False))
    except (PermissionError, RampsError, RuntimeError, TimeoutError) as exc:
        fail(str(exc))
    emit([rep], lambda r, console: console.print(r.table(), highlight=False, markup=False), as_json=as_json,
         out_file=out_file)


@experiment_app.command("origin-restart")
def testbed_experiment_origin_restart(
    down: Optional[list[float]] = typer.Option(None, "--down", help="seconds the origin's node stays down before its supervisor starts it again (repeatable; default: 5 and 60)"),
    cut: float = typer.Option(0.0, "--cut", min=0.0, help="also cut the origin robot's link for this many seconds from the crash"),
    programs: int = typer.Option(15, "--programs", min=1, max=200, help="programs in flight when the node is killed"),
    robots: int = typer.Option(5, "--robots", min=2, max=8, help="robots (r1 is the origin)"),
    units: float = typer.Option(1.5, "--units", min=0.05, help="work units of each program"),
    origin_hold: Optional[float] = typer.Option(None, "--origin-hold", min=0.0, help="seconds hosts keep an absent origin's programs (default: the node's, 30)"),
    as_json: bool = typer.Option(False, "--json", help="write the report as JSON to stdout"),
    out_file: Optional[Path] = typer.Option(None, "--out", help="also save the JSON here"),
) -> None:
    """Kill the origin's node (SIGKILL, the node alone) with programs in flight, start it again
    DOWN s later as a supervisor would, and count what its waiting client receives: every program
    once, with how many its hosts kept running through the crash and how many ran again."""
    from ramps.errors import RampsError
    from ramps.lab.restart import run_origin_restart

    runs = []
    try:
        for d in down or [5.0, 60.0]:
            err.print(f"origin restart after {max(d, cut):g} s" + (f" (link cut {cut:g} s)" if cut else ""),
                      highlight=False)
            runs.append(run_origin_restart(d, cut=cut, programs=programs, robots=robots, units=units,
                                           origin_hold=origin_hold, log=lambda m: err.print(m, highlight=False)))
    except (PermissionError, RampsError, RuntimeError, TimeoutError) as exc:
        fail(str(exc))

    def table(r, console):
        console.print(f"down {r.down:g} s, cut {r.cut:g} s: {r.delivered}/{r.programs} delivered, {r.lost} lost, "
                      f"{r.duplicated} duplicated, {r.wrong} wrong; {r.kept} kept running by their hosts, "
                      f"{r.dropped} dropped by them (the origin away too long), "
                      f"{r.again} placed again; {r.resumed} resumed from the record; last outcome "
                      f"{r.seconds_to_last:g} s after the crash; before the crash: {r.before}"
                      + (f"; first error: {r.error}" if r.error else ""), highlight=False, markup=False)

    emit(runs, table, as_json=as_json, out_file=out_file)
    if any(r.lost or r.duplicated or r.wrong for r in runs):
        raise typer.Exit(1)


@experiment_app.command("rolling-restart")
def testbed_experiment_rolling_restart(
    robots: int = typer.Option(8, "--robots", min=2, max=12, help="robots in the team"),
    origins: int = typer.Option(3, "--origins", min=1, max=8, help="robots whose applications submit (r1..rN)"),
    period: float = typer.Option(0.5, "--period", min=0.05, help="seconds between two submissions of each application"),
    units: float = typer.Option(0.3, "--units", min=0.01, help="work units of each program"),
    settle: float = typer.Option(15.0, "--settle", min=3.0, help="seconds of submissions before and after the roll"),
    as_json: bool = typer.Option(False, "--json", help="write the report as JSON to stdout"),
    out_file: Optional[Path] = typer.Option(None, "--out", help="also save the JSON here"),
) -> None:
    """Restart every node of the team one by one, as a rolling upgrade does (SIGTERM, start again,
    wait until it is back; the origins last), while applications on ORIGINS robots submit
    continuously; count lost and duplicated programs and print the delivery rate before, during
    and after the roll."""
    from ramps.errors import RampsError
    from ramps.lab.restart import run_rolling_restart

    if origins > robots:
        fail(f"--origins ({origins}) cannot exceed --robots ({robots})")
    try:
        rep = run_rolling_restart(robots=robots, origins=origins, period=period, units=units, settle=settle,
                                  log=lambda m: err.print(m, highlight=False))
    except (PermissionError, RampsError, RuntimeError, TimeoutError) as exc:
        fail(str(exc))

    def table(r, console):
        console.print(f"rolling restart of {r.robots} nodes, origins {', '.join(r.origins)}: {r.submitted} submitted, "
                      f"{r.delivered} delivered, {r.lost} lost, {r.duplicated} duplicated, {r.wrong} wrong; "
                      f"delivered per second before / during / after the roll: {r.rate_before:g} / "
                      f"{r.rate_during:g} / {r.rate_after:g}; each node back after (s): {r.restarts}"
                      + (f"; first error: {r.error}" if r.error else ""), highlight=False, markup=False)

    emit([rep], table, as_json=as_json, out_file=out_file)
    if rep.lost or rep.duplicated or rep.wrong:
        raise typer.Exit(1)


@experiment_app.command("peers")
def testbed_experiment_peers(
    scenario: Optional[list[str]] = typer.Option(None, "--scenario", "-s", help="run only these (repeatable): idle, busy-1, busy-2, busy-4, origins, crash (default: all)"),
    engine: Optional[list[str]] = typer.Option(None, "--engine", "-e", help="run only these (repeatable): ramps, round-robin, ray, dask, and ramps-nice0 (ramps with its programs at nice 0: what its default nice 10 costs and protects on busy robots) (default: the first four)"),
    programs: Optional[int] = typer.Option(None, "--programs", min=1, max=500, help="programs in every scenario, split between its origins (default: 30, 15 with the crash)"),
    work: float = typer.Option(1.5, "--work", min=0.05, max=20.0, help="work units of each burn program (1.5: about 19-28 s alone on an emulated core)"),
    quota: float = typer.Option(0.32, "--quota", min=0.05, max=4.0, help="host cores of each robot"),
    cores: int = typer.Option(4, "--cores", min=1, max=16, help="emulated cores of each robot (Ray's --num-cpus, Dask's --nworkers)"),
    keep_logs: Optional[Path] = typer.Option(None, "--keep-logs", help="keep each ramps run's node logs and traces in this folder (<scenario>-<engine>/, under round-<n>/ with --repeats)"),
    timeout: float = typer.Option(1500.0, "--timeout", min=10.0, help="seconds an engine's burst may take; programs still running then are reported as not done, with no makespan"),
    peer_nice: int = typer.Option(10, "--peer-nice", min=0, max=19, help="niceness of Ray's and Dask's programs (10: as ramps' workers, fair to a busy robot's own software; 0: as they run out of the box); their daemons run at 0, as ramps node"),
    repeats: int = typer.Option(1, "--repeats", min=1, max=20, help="rounds of every engine in turns, with each engine's median makespan: the host's speed drifts more between runs than engines differ on idle robots"),
    as_json: bool = typer.Option(False, "--json", help="write the report as JSON to stdout"),
    out_file: Optional[Path] = typer.Option(None, "--out", help="also save the JSON here"),
) -> None:
    """ramps beside round robin, Ray and Dask on the same emulated robots (5 robots of 4 cores,
    burn programs from r1): idle, 1/2/4 robots busy, several origins, and a robot crashed at 10 s;
    prints every engine's makespan, distribution and lost programs beside the ideal. Each engine
    runs each scenario on a fresh testbed; Ray and Dask need the peers extra, `pip install -e
    '.[peers]'` (skipped without it). 1-3 minutes per scenario and engine with the defaults, but 7-11 minutes where
    nice-10 programs land beside a busy robot's load (round robin; Ray and Dask at --peer-nice 10),
    so 1.5-2.5 hours for all 24 runs."""
    from ramps.errors import RampsError
    from ramps.lab.peers import DEFAULT_ENGINES, ENGINES, run_peers
    from ramps.lab.peers_scenarios import SCENARIOS, Setup, format_report

    for name, known, what in ((scenario, SCENARIOS, "scenario"), (engine, ENGINES, "engine")):
        bad = [n for n in name or [] if n not in known]
        if bad:
            fail(f"unknown {what} {bad[0]!r}: choose from {', '.join(known)}")
    chosen = [SCENARIOS[s].with_programs(programs) for s in (scenario or SCENARIOS)]
    engines = list(engine or DEFAULT_ENGINES)
    err.print(f"{len(chosen)} scenario(s) x {len(engines)} engine(s), each run on a fresh testbed ...")
    try:
        rep = run_peers(chosen, engines, Setup(cores=cores, quota=quota, work=work, peer_nice=peer_nice, timeout=timeout,
                                         keep_logs=str(keep_logs) if keep_logs else None),
                        repeats=repeats, log=lambda m: err.print(m, highlight=False, markup=False))
    except (PermissionError, RampsError, RuntimeError, ValueError) as exc:
        fail(str(exc))
    emit([rep], lambda r, console: console.print(format_report(r), highlight=False, markup=False), as_json=as_json,
         out_file=out_file)
