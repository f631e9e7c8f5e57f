"""``ramps testbed``: emulated robots on this Linux host (root).

    ramps testbed up -n 5            # five robots: a network namespace and a cpu cgroup each
    ramps testbed status
    ramps testbed crash r3           # also cut, freeze, recover, lossy (one table: FAULTS)
    ramps testbed experiment faults  # the paper's Tables 5-10 on real processes
    ramps testbed experiment peers   # ramps beside round robin, Ray and Dask
    ramps testbed down

The work is done by ``ramps.testbed`` (the emulated team) and ``ramps.lab``
(``fidelity``, ``campaign``); this module parses and prints (rules in
``ramps.cli.common``). The ``experiment`` subcommands are in
``ramps.cli.testbed_experiments``.
"""

from __future__ import annotations

import inspect
import json
import sys
from pathlib import Path
from typing import Annotated, Any, Callable, NamedTuple, Optional

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
    out,
)
from ramps.cli.testbed_experiments import experiment_app


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
    loaded: Optional[list[str]] = typer.Option(None, "--loaded", metavar="ROBOT[=N]", help="robot with background load, ROBOT or ROBOT=N busy processes (repeatable; N default 4)"),
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

testbed_app.add_typer(experiment_app, name="experiment")



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
    from ramps.lab.fidelity import run_fidelity

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
    stress: bool = typer.Option(True, "--stress/--no-stress", help="also stall nodes alone (0.5-5 s, the origin too), kill nodes alone, crash origins (robot or node; the application submits lost programs again), and put CPU pressure on robots; then check nothing was restarted without cause or left running (--no-stress: crashes, cuts and freezes only)"),
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
    from ramps.lab.campaign import run_campaign

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

