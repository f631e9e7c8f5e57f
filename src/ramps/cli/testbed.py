"""``ramps testbed``: emulated robots on this Linux host (root).

    ramps testbed up -n 5            # five robots: a network namespace and a cpu cgroup each
    ramps testbed status
    ramps testbed crash r3           # also cut, freeze, recover, lossy (one table: FAULTS)
    ramps testbed experiment faults  # the paper's Tables 5-10 on real processes
    ramps testbed experiment peers   # ramps beside round robin, Ray and Dask
    ramps testbed down

The work is done by ``ramps.testbed``; this module parses and prints (rules
in ``ramps.cli.common``).
"""

from __future__ import annotations

import inspect
import json
import sys
from pathlib import Path
from typing import Annotated, Any, Callable, NamedTuple, Optional

import msgspec
import typer

from ramps.cli.common import (
    POLICY_HELP,
    DiscoveryOption,
    LeaseOption,
    PolicyOption,
    check_discovery,
    check_policy,
    command_group,
    emit,
    err,
    fail,
    fault_plans,
    out,
    save_json,
)


testbed_app = command_group("Emulated robots on this Linux host (root): one network namespace and cpu cgroup "
                            "per robot, with fault injection.")
TB_HELP = "testbed id (default: the only one up)"


def _tb_attach(tb):
    from ramps.testbed import Testbed, TestbedError

    try:
        return Testbed.attach(tb)
    except (PermissionError, TestbedError) as exc:
        fail(str(exc))


@testbed_app.command("up")
def testbed_up(
    robots: int = typer.Option(5, "--robots", "-n", min=1, max=250, help="number of robots r1..rN"),
    quota: Optional[float] = typer.Option(None, "--quota", help="host cores per robot (default: host cores / robots)"),
    cores: Optional[int] = typer.Option(None, "--cores", min=1, help="cores each node offers (default: quota rounded)"),
    loaded: Optional[list[str]] = typer.Option(None, "--loaded", help="robot with background load, ROBOT or ROBOT=N busy processes (repeatable; N default 4)"),
    team: Optional[str] = typer.Option(None, "--team", "-t", help="team name (default: tb-<id>)"),
    lease_ms: LeaseOption = None,
    policy: PolicyOption = None,
    program: Optional[list[str]] = typer.Option(None, "--program", help="extra program as package.module:function (repeatable)"),
    discovery: DiscoveryOption = "both",
    caps: bool = typer.Option(True, "--caps/--no-caps", help="cap every program (and busy process) at its processor-sharing share of the robot (cgroup v1)"),
) -> None:
    """Start a testbed and leave it running; prints the robots and how to connect."""
    from ramps.errors import RampsError
    from ramps.testbed import Testbed

    if policy is not None:
        check_policy(policy)
    check_discovery(discovery)
    load: dict[str, int] = {}
    for item in loaded or []:
        name, _, n = item.partition("=")
        if n and not n.isdigit():
            fail(f"--loaded must look like r5 or r5=4, got {item!r}")
        load[name] = int(n) if n else 4
    try:
        tb = Testbed(robots, team=team, quota=quota, cores=cores, loaded=load, lease_ms=lease_ms, policy=policy,
                     programs=program or None, discovery=discovery, caps=caps)
        err.print(f"starting {robots} robots ...")
        tb.up()
        tb.detach()
    except (PermissionError, ValueError, RampsError) as exc:
        fail(str(exc))
    st = tb.status()
    out.print(f"testbed [bold]{tb.tb}[/]: team [bold]{tb.team}[/], bridge {st['bridge']} ({st['subnet']}), "
              f"{tb.quota:g} host cores per robot (cgroup {tb.mode})", highlight=False)
    for r in st["robots"]:
        out.print(f"  {r['robot']:6s} {r['ip']:15s} namespace {r['namespace']:16s} pid {r['pid']}"
                  + (f"  load {r['load']}" if r["load"] else ""), highlight=False)
    out.print(f"connect: ramps status --team {tb.team} --no-multicast "
              + " ".join(f"-c {e}" for e in tb.endpoints()), highlight=False, soft_wrap=True)
    out.print(f"python:  ramps.connect(team={tb.team!r}, robot='r1', multicast=False, connect={tb.endpoints()!r})",
              highlight=False, soft_wrap=True)
    out.print("faults:  ramps testbed crash|cut|freeze|recover ROBOT; stop: ramps testbed down", highlight=False)


@testbed_app.command("status")
def testbed_status(
    tb: Optional[str] = typer.Option(None, "--tb", help=TB_HELP),
    as_json: bool = typer.Option(False, "--json", help="write the status as JSON to stdout"),
    no_team: bool = typer.Option(False, "--no-team", help="skip the team view (no client session)"),
) -> None:
    """Namespaces, links and processes per robot, and the team as a client sees it."""
    from rich.table import Table

    bed = _tb_attach(tb)
    st = bed.status(team_view=not no_team)
    if as_json:
        sys.stdout.write(json.dumps(st, indent=1) + "\n")
        return
    view = {r["robot"]: r for r in st.get("team_view", [])}
    table = Table(title=f"testbed {st['tb']}: team {st['team']}, {st['subnet']}, {st['quota']:g} host cores/robot",
                  title_justify="left")
    for col in ("robot", "ip", "namespace", "link", "node", "load", "faults", "team: alive", "cores", "busy", "sees"):
        table.add_column(col)
    for r in st["robots"]:
        v = view.get(r["robot"])
        table.add_row(r["robot"], r["ip"], r["namespace"] or "missing", r["link"], f"{r['process']} ({r['pid']})",
                      f"{r['load_running']}/{r['load']}", ",".join(r["faults"]) or "-",
                      ("no" if "team_view" in st else "-") if v is None else ("yes" if v["alive"] else "no"),
                      str(v.get("cores", "-")) if v else "-", f"{v['cpu_busy']:.2f}" if v and "cpu_busy" in v else "-",
                      "-" if not v or v.get("sees") is None else str(v["sees"]))
    out.print(table)
    if "team_view_error" in st:
        err.print(f"team view: {st['team_view_error']}", highlight=False, soft_wrap=True)


class Fault(NamedTuple):
    """One ``ramps testbed FAULT ROBOT`` command: the ``Testbed`` method of
    that name is called with the robot (and ``extra``'s arguments, in order),
    and ``done(robot, result, bed, *args)`` is the line printed after it."""

    help: str
    done: Callable[..., str]
    extra: tuple[inspect.Parameter, ...] = ()


RobotArgument = Annotated[str, typer.Argument(help="robot, e.g. r3")]
TestbedOption = Annotated[Optional[str], typer.Option("--tb", help=TB_HELP)]
LOSS = inspect.Parameter("loss", inspect.Parameter.POSITIONAL_OR_KEYWORD, annotation=Annotated[
    float, typer.Argument(min=0.0, max=1.0, help="drop probability of each packet, 0-1 (0 ends it)")])

# The fault commands, generated below in this order.
FAULTS: dict[str, Fault] = {
    "crash": Fault("SIGKILL a robot's node, workers and load.", lambda robot, res, bed: f"{robot}: crashed (SIGKILL)"),
    "cut": Fault("Take a robot's network link down (it keeps computing).",
                 lambda robot, res, bed: f"{robot}: cut off (link down)"),
    "freeze": Fault("SIGSTOP every process of a robot.", lambda robot, res, bed: f"{robot}: frozen (SIGSTOP)"),
    "recover": Fault("Undo a robot's faults: link up, SIGCONT, restart a crashed node; waits until it is alive.",
                     lambda robot, res, bed: f"{robot}: recovered ({', '.join(res) or 'nothing to undo'}); "
                                             f"alive in team {bed.team}"),
    "lossy": Fault("Make a robot's link lossy (a poor WiFi link): each packet in and out is dropped with this "
                   "probability.",
                   lambda robot, res, bed, loss: f"{robot}: {loss:.0%} packet loss" if loss else f"{robot}: loss removed",
                   (LOSS,)),
}


def _tb_fault(kind: str, robot: str, tb: Optional[str], *args: Any) -> None:
    from ramps.errors import RampsError
    from ramps.testbed.net import NetError

    bed = _tb_attach(tb)
    try:
        res = getattr(bed, kind)(robot, *args)
    except (RampsError, NetError, ValueError) as exc:
        fail(str(exc))
    out.print(FAULTS[kind].done(robot, res, bed, *args), highlight=False)


def _fault_command(kind: str, fault: Fault) -> Callable[..., None]:
    def command(robot: str, tb: Optional[str] = None, **extra: Any) -> None:
        _tb_fault(kind, robot, tb, *(extra[p.name] for p in fault.extra))

    kw = inspect.Parameter.POSITIONAL_OR_KEYWORD
    command.__signature__ = inspect.Signature(  # type: ignore[attr-defined]  # what typer reads
        [inspect.Parameter("robot", kw, annotation=RobotArgument), *fault.extra,
         inspect.Parameter("tb", kw, default=None, annotation=TestbedOption)])
    command.__name__ = command.__qualname__ = f"testbed_{kind}"
    command.__doc__ = fault.help
    return command


for _kind, _fault in FAULTS.items():
    testbed_app.command(_kind)(_fault_command(_kind, _fault))


experiment_app = command_group("The paper's experiments on real processes (each run starts its own testbed).")
testbed_app.add_typer(experiment_app, name="experiment")


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
    from ramps.testbed.experiments import run_plan

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
    from ramps.testbed.sweeps import DEFAULT_CONFIGS, EXPERIMENTS, FULL_CONFIGS, format_report, run_testbed_sweep

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
    from ramps.testbed.slowlink import format_report, run_slow_link

    try:
        rep = run_slow_link(told_speed=told_speed, rate=rate * 1e6, payload=payload, units=units, programs=programs,
                            log=lambda m: err.print(m, highlight=False), keep_logs=keep_logs)
    except (PermissionError, RampsError, RuntimeError, TimeoutError) as exc:
        fail(str(exc))
    emit([rep], lambda r, console: console.print(format_report(r), highlight=False), as_json=as_json,
         out_file=out_file)


__import__("ramps.cli.sites", fromlist=["register"]).register(experiment_app)  # experiment sites


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
    from ramps.testbed.late_load import VARIANTS, format_report, run_testbed_relocation

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


@experiment_app.command("speeds")
def testbed_experiment_speeds(
    starts: int = typer.Option(10, "--starts", min=1, max=100, help="fresh testbeds to start, one after another"),
    robots: int = typer.Option(5, "--robots", min=2, max=20, help="identical robots in each"),
    cores: int = typer.Option(4, "--cores", min=1, max=16, help="emulated cores of each robot"),
    quota: float = typer.Option(0.32, "--quota", min=0.05, max=4.0, help="host cores of each robot"),
    loaded: int = typer.Option(0, "--loaded", min=0, max=32, help="busy processes each robot's own software starts beside its node"),
    as_json: bool = typer.Option(False, "--json", help="write the report as JSON to stdout"),
    out_file: Optional[Path] = typer.Option(None, "--out", help="also save the JSON here"),
) -> None:
    """Do identical robots measure themselves alike? Starts a team of identical robots again and
    again, every node measuring its own speed (nothing handed in, as on real robots), and prints each
    node's boot speed and the speeds they report 2, 10 and 20 s later, with the spread (fastest over
    slowest) of each start. About 35 s per start."""
    from ramps.errors import RampsError
    from ramps.testbed.speeds import run_speeds

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
    from ramps.testbed.restart import run_origin_restart

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
    from ramps.testbed.restart import run_rolling_restart

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
    keep_logs: Optional[Path] = typer.Option(None, "--keep-logs", help="keep each ramps run's node logs and traces in this folder (<scenario>-<engine>/)"),
    timeout: float = typer.Option(1500.0, "--timeout", min=10.0, help="seconds an engine's burst may take; programs still running then are reported as not done, with no makespan"),
    peer_nice: int = typer.Option(10, "--peer-nice", min=0, max=19, help="niceness of Ray's and Dask's programs (10: as ramps' workers, fair to a busy robot's own software; 0: as they run out of the box); their daemons run at 0, as ramps node"),
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
    from ramps.testbed.peers import DEFAULT_ENGINES, ENGINES, SCENARIOS, Setup, format_report, run_peers

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
                        log=lambda m: err.print(m, highlight=False, markup=False))
    except (PermissionError, RampsError, RuntimeError, ValueError) as exc:
        fail(str(exc))
    emit([rep], lambda r, console: console.print(format_report(r), highlight=False, markup=False), as_json=as_json,
         out_file=out_file)


@testbed_app.command("fidelity")
def testbed_fidelity(
    caps: bool = typer.Option(True, "--caps/--no-caps", help="per-program CPU caps (the default; --no-caps to see why)"),
    cores: int = typer.Option(4, "--cores", min=1, max=64, help="emulated cores of the robot"),
    quota: float = typer.Option(0.8, "--quota", min=0.05, help="host cores of the robot"),
    work: float = typer.Option(2.0, "--work", min=0.1, help="work units per program"),
    case: Optional[list[str]] = typer.Option(None, "--case", help="PROGRAMS,BUSY: run only these cases (repeatable), e.g. --case 15,0 --case 4,0 (default: 8 cases from 1 to 8 programs, 0 or 2 busy)"),
    told_speed: bool = typer.Option(False, "--told-speed", help="ablation: hand every node the speed measured before the start (--speed) instead of letting each measure itself, as robots do"),
    as_json: bool = typer.Option(False, "--json", help="write the report as JSON to stdout"),
    out_file: Optional[Path] = typer.Option(None, "--out", help="also save the JSON here"),
) -> None:
    """How closely a testbed robot follows processor sharing: k programs next to b busy
    processes, completion times and the robot's CPU against the model, and the CPU the robot
    spent outside its programs (node, fork server) (about 5 minutes for the 8 default cases, less with --case)."""
    from ramps.errors import RampsError
    from ramps.testbed.fidelity import run_fidelity

    cases: list[tuple[int, int]] = []
    for c in case or []:
        try:
            k, b = (int(x) for x in c.split(","))
        except ValueError:
            fail(f"--case {c!r}: expected PROGRAMS,BUSY, two whole numbers, e.g. 15,0")
        if not (1 <= k <= 200 and 0 <= b <= 64):
            fail(f"--case {c!r}: programs must be 1-200 and busy processes 0-64")
        cases.append((k, b))

    def show(rep, console) -> None:
        from rich.table import Table

        t = Table(title=f"testbed robot of {rep.cores} cores on {rep.quota:g} host cores, "
                        f"per-program caps {'on' if rep.caps else 'off'}, {rep.work:g} units each")
        for col in ("programs", "busy", "model s", "measured s", "range s", "error", "robot CPU", "model CPU",
                    "unit CPU s", "corrected error", "corrected last", "CPU s outside programs", "node cores",
                    "cost model s", "vs it, last"):
            t.add_column(col, justify="right")
        for c in rep.cases:
            t.add_row(str(c.programs), str(c.busy), f"{c.model:.1f}", f"{c.mean:.1f}", f"{c.first:.1f}-{c.last:.1f}",
                      f"{c.error:+.0%}", f"{c.cpu:.2f}", f"{c.cpu_model:.2f}", f"{c.unit_cpu:.2f}",
                      f"{c.corrected_error:+.0%}", f"{c.corrected_last_error:+.0%}",
                      f"{c.overhead_cpu_s:.1f} of {c.robot_cpu_s:.1f}", f"{c.node_cores:.2f}", f"{c.cost_model:.1f}",
                      f"{c.cost_model_last_error:+.0%}")
        console.print(t)
        console.print(f"mean |error|: completion {rep.mean_abs_error:.0%}, robot CPU {rep.mean_abs_cpu_error:.0%}, "
                      f"completion corrected for the host's speed {rep.mean_abs_corrected_error:.0%}; a work unit "
                      f"cost {rep.unit_cpu_s[0]:.2f} then {rep.unit_cpu_s[1]:.2f} CPU s in this process",
                      highlight=False)

    err.print(f"fidelity of one testbed robot, caps {'on' if caps else 'off'} ...")
    try:
        rep = run_fidelity(told_speed=told_speed, caps=caps, cores=cores, quota=quota, work=work, cases=cases or None,
                           log=lambda m: err.print(m, highlight=False))
    except (PermissionError, RampsError, RuntimeError) as exc:
        fail(str(exc))
    emit([rep], show, as_json=as_json, out_file=out_file)


@testbed_app.command("campaign")
def testbed_campaign(
    runs: int = typer.Option(20, "--runs", min=1, help="number of runs (each starts its own testbed)"),
    seed: int = typer.Option(0, "--seed", help="seed of the first run; run i uses seed*1000000+i"),
    robots: int = typer.Option(4, "--robots", min=2, max=8, help="robots per run (r1 is the origin)"),
    duration: float = typer.Option(20.0, "--duration", min=5.0, help="seconds of workload and faults per run"),
    policy: str = typer.Option("ramps", "--policy", "-p", help=POLICY_HELP),
    lease_ms: LeaseOption = None,
    discovery: DiscoveryOption = "both",
    keep_logs: Optional[Path] = typer.Option(None, "--keep-logs", help="keep the node logs and traces of failed runs here"),
    only_seed: Optional[int] = typer.Option(None, "--only-seed", help="re-run just this run seed (as printed by a failed run)"),
    stress: bool = typer.Option(True, "--stress/--no-stress", help="also stall nodes alone (0.5-5 s, the origin too), kill nodes alone, crash origins (robot or node; the application submits lost programs again), and put CPU pressure on robots; then check nothing was restarted without cause or left running (--no-stress: crashes, cuts and freezes only, as before 2026-11-23)"),
    told_speed: bool = typer.Option(False, "--told-speed", help="ablation: hand every node the speed measured before the start (--speed) instead of letting each measure itself, as robots do"),
    origin_faults: float = typer.Option(0.5, "--origin-faults", min=0.0, max=1.0, help="with --stress: the chance that each origin stalls or crashes (robot or node) in a run, and is started again 1-4 s later"),
    as_json: bool = typer.Option(False, "--json", help="write the report as JSON to stdout"),
    out_file: Optional[Path] = typer.Option(None, "--out", help="also save the JSON here"),
) -> None:
    """Random crashes, cuts, freezes and recoveries of non-origin robots during a workload, on real
    processes; after every run: every program completed exactly once, recovered robots rejoined.
    With --stress (default) also node-only stalls and crashes, origin stalls and crashes, and CPU
    pressure, and the checks that no program was restarted without cause and nothing was left running."""
    from ramps.errors import RampsError
    from ramps.experiments.report import print_campaign
    from ramps.testbed.experiments import run_campaign

    check_policy(policy)
    check_discovery(discovery)

    def progress(done, total, run):
        mark = "ok" if run.ok else (f"FAILED lost {run.lost} dup {run.duplicated} not rejoined {run.not_rejoined}"
                                    + (f" unexplained restarts {run.unexplained}" if run.unexplained else "")
                                    + (f" left running {run.left_running}" if run.left_running else "")
                                    + (f" orphans {run.orphans}" if run.orphans else ""))
        if run.resubmitted:
            mark += f" ({run.resubmitted} submitted again after their origin crashed)"
        err.print(f"run {done}/{total} (seed {run.seed}): {run.programs} programs, "
                  f"{sum(1 for f in run.faults if f[2] != 'recover')} faults, {run.seconds:.0f} s: {mark}",
                  highlight=False)

    try:
        rep = run_campaign(runs, seed, told_speed=told_speed, policy=policy, robots=robots, duration=duration, lease_ms=lease_ms,
                           discovery=discovery, keep_logs=keep_logs, only_seed=only_seed, progress=progress,
                           stress=stress, origin_fault_p=origin_faults)
    except (PermissionError, RampsError) as exc:
        fail(str(exc))
    if rep.interrupted:
        err.print(f"interrupted: the {rep.runs} run(s) that finished follow")
    emit([rep], print_campaign, as_json=as_json, out_file=out_file)
    if stress:
        err.print(f"stress checks: {rep.unexplained_restarts} unexplained restart(s), {rep.left_running} robot(s) "
                  f"left running programs, {rep.orphans} orphaned process(es) of nodes killed alone; "
                  f"{rep.resubmitted} program(s) submitted again after their origin crashed", highlight=False)
    if rep.interrupted:
        raise typer.Exit(130)
    if rep.lost or rep.duplicated or rep.not_rejoined or rep.unexplained_restarts or rep.left_running or rep.orphans:
        raise typer.Exit(1)


@testbed_app.command("down")
def testbed_down(tb: Optional[str] = typer.Option(None, "--tb", help=TB_HELP),
                 all_: bool = typer.Option(False, "--all", help="remove every testbed and every leftover "
                                           "(ramps-* namespaces, rb-* links, testbed cgroups)")) -> None:
    """Stop a testbed and remove everything it made."""
    from ramps.testbed import down_all

    if all_:
        try:
            gone = down_all()
        except PermissionError as exc:
            fail(str(exc))
        out.print("removed: " + (", ".join(gone) if gone else "nothing was left"), highlight=False, soft_wrap=True)
        return
    bed = _tb_attach(tb)
    bed.down()
    out.print(f"testbed {bed.tb} is down")

