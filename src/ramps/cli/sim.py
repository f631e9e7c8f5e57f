"""``ramps sim``: teams and workloads in virtual time.

    ramps sim paper                  # the paper's Tables 3-4 (and --experiment faults: Tables 5-10)
    ramps sim sweep                  # several origins at once, against the best achievable
    ramps sim campaign               # random faults, invariants checked after every run
    ramps sim relocation             # a robot gets busy after placement: relocation on/off vs hindsight
    ramps sim accelerators           # accelerator placement against the CP-SAT optimum
    ramps sim battery                # robots below their battery reserve, against the exact optimum
    ramps sim energy                 # makespan against energy as placement weighs energy
    ramps sim run examples/warehouse.yaml   # your own team and workload

The work is done by ``ramps.experiments`` and ``ramps.sim``; this module
parses and prints (rules in ``ramps.cli.common``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import msgspec
import typer
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TaskID, TextColumn, TimeElapsedColumn

from ramps.cli.common import POLICY_HELP, check_policy, command_group, emit, err, fail, fault_plans

sim_app = command_group("Simulate teams and workloads in virtual time (seconds for hours of robot time).")


@sim_app.command("paper")
def sim_paper(
    experiment: str = typer.Option("all", "--experiment", "-e",
                                   help="unloaded (Table 3, Figs 3-4), loaded (Table 4, Figs 5-6), "
                                        "faults (Tables 5-10), or all (unloaded and loaded)"),
    mode: str = typer.Option("all", "--mode", help="faults: sequential, simultaneous or all"),
    kind: str = typer.Option("all", "--kind", help="faults: crash, network, mixed or all"),
    policy: str = typer.Option("ramps", "--policy", "-p", help=POLICY_HELP),
    runs: int = typer.Option(3, "--runs", "-n", min=1, help="runs per configuration (the paper used 3)"),
    seed: int = typer.Option(0, "--seed", help="base seed; the same seed gives the same results"),
    as_json: bool = typer.Option(False, "--json", help="write the results as JSON to stdout instead of tables"),
    out_file: Optional[Path] = typer.Option(None, "--out", "-o", help="also save the JSON to this file"),
    plot: Optional[Path] = typer.Option(None, "--plot", help="draw the paper's figures (ours beside the paper's "
                                        "values) as PNGs into this directory; runs configurations in parallel"),
) -> None:
    """Regenerate the paper's load-distribution experiments in the simulator.

    Each configuration runs the chosen policy, round robin and a single robot
    on the same simulated team and seed, and prints the distribution per
    robot, makespan, speedup, ratio to round robin and the paper's
    classification (optimal / near optimal / non optimal).
    """
    from ramps.experiments.paper import EXPERIMENTS, configurations, run_experiment
    from ramps.experiments.report import print_experiment

    check_policy(policy)
    if plot is not None:
        from ramps.cli.observe import sim_paper_plot

        sim_paper_plot(plot, experiment, policy=policy, runs=runs, seed=seed, out_file=out_file)
        return
    if experiment == "faults":
        _sim_faults(mode, kind, policy=policy, runs=runs, seed=seed, as_json=as_json, out_file=out_file)
        return
    wanted = list(EXPERIMENTS) if experiment == "all" else [experiment]
    if any(e not in EXPERIMENTS for e in wanted):
        fail(f"unknown experiment {experiment!r}; choose unloaded, loaded or all")
    reports = []
    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                  console=err, transient=True) as progress:
        for e in wanted:
            task = progress.add_task(f"{e} / {policy}", total=len(configurations(e)))

            def advance(done: int, total: int, t: TaskID = task) -> None:
                progress.update(t, completed=done)

            reports.append(run_experiment(e, policy=policy, runs=runs, seed=seed, progress=advance))
    emit(reports, print_experiment, as_json=as_json, out_file=out_file)


def _sim_faults(mode: str, kind: str, *, policy: str, runs: int, seed: int, as_json: bool,
                out_file: Optional[Path]) -> None:
    from ramps.experiments.faults import KINDS, run_fault_experiment
    from ramps.experiments.report import print_fault_report

    modes, kinds = fault_plans(mode, kind, KINDS)
    reports = [run_fault_experiment(m, k, policy=policy, runs=runs, seed=seed) for m in modes for k in kinds]
    emit(reports, print_fault_report, as_json=as_json, out_file=out_file)
    if any(r.summary["lost"] or r.summary["duplicated"] for r in reports):
        raise typer.Exit(1)


@sim_app.command("sweep")
def sim_sweep(
    family: str = typer.Option("multi-origin", "--family", "-f",
                               help="multi-origin (all six below), or one of idle-burst, idle-staggered, "
                                    "loaded-burst, loaded-staggered, mixed-burst, mixed-staggered"),
    scenarios: int = typer.Option(36, "--scenarios", "-n", min=1, help="generated scenarios per family"),
    seeds: int = typer.Option(3, "--seeds", min=1, help="simulation seeds per scenario"),
    policy: str = typer.Option("ramps", "--policy", "-p", help=POLICY_HELP),
    seed: int = typer.Option(0, "--seed", help="generates the scenarios; the same seed gives the same sweep"),
    settings: list[str] = typer.Option([], "--set", help="change a core setting in every scenario, e.g. "
                                       "--set prompt_reports=false --set max_rejections=3 (see RampsConfig)"),
    exact_seconds: float = typer.Option(5.0, "--exact-seconds", min=0.0,
                                        help="seconds per scenario to prove the exact optimum where the bound "
                                             "and the oracle differ (a better schedule, a stronger bound, then "
                                             "a search); one that runs out reports the interval the optimum "
                                             "lies in. 0: no search (with --exact-nodes 0)"),
    exact_nodes: int = typer.Option(0, "--exact-nodes", min=0,
                                    help="also stop each search after this many placements (0: no limit), so "
                                         "that the result does not depend on the machine's speed"),
    online_seconds: float = typer.Option(0.0, "--online-seconds", min=0.0,
                                         help="where the policy ends more than 5% above the best bound, seconds "
                                              "to show how close any placement deciding each program at its "
                                              "release can get (the clairvoyant optimum knows the future; "
                                              "column \"online\"). 0: not shown"),
    only: list[str] = typer.Option([], "--only", help="run only this scenario (repeatable), e.g. --only "
                                                      "mixed-staggered-1"),
    as_json: bool = typer.Option(False, "--json", help="write the results as JSON to stdout instead of tables"),
    out_file: Optional[Path] = typer.Option(None, "--out", "-o", help="also save the JSON to this file"),
) -> None:
    """Several origins at once: generated teams of 3-20 robots where 2 to all
    of them submit programs in one burst or staggered over 10 s, each run
    compared with the best achievable under the same model.

    A family is a kind of team (idle and identical, some robots running busy
    processes, or mixed cores and speeds) and a timing. Each scenario runs
    the chosen policy and round robin on the same seeds. The table shows the
    median makespan divided by a lower bound no schedule can beat, and by an
    omniscient central scheduler, and with the exact optimum where a search
    proves it within --exact-seconds (else the interval it lies in); the
    default sweep (216 scenarios x 3 seeds) takes 15-30 minutes on two cores.
    """
    from ramps.experiments.report import print_sweep
    from ramps.experiments.sweep import FAMILIES, TEAMS, TIMINGS, run_sweep

    check_policy(policy)
    if family not in FAMILIES:
        fail(f"unknown family {family!r}; choose multi-origin or one of "
             + ", ".join(f"{t}-{s}" for t in TEAMS for s in TIMINGS))
    config = _config_with(settings) if settings else None
    total = len(only) or scenarios * len(FAMILIES[family])
    with Progress(TextColumn(f"sweep {family} / {policy}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                  console=err, transient=True) as progress:
        task = progress.add_task("sweep", total=total)
        try:
            rep = run_sweep(family, per_family=scenarios, seeds=seeds, seed=seed, policy=policy, config=config,
                            progress=lambda done, total: progress.update(task, completed=done),
                            exact_nodes=exact_nodes, exact_seconds=exact_seconds, online_seconds=online_seconds,
                            only=only)
        except ValueError as exc:
            fail(str(exc))
    emit([rep], print_sweep, as_json=as_json, out_file=out_file)


def _config_with(settings: list[str]):
    """RampsConfig with NAME=VALUE changes, each checked against the field's type."""
    from ramps.core.config import RampsConfig

    changes: dict[str, object] = {}
    for item in settings:
        name, sep, value = item.partition("=")
        if not sep or name not in RampsConfig.__struct_fields__:
            fail(f"--set {item!r}: expected NAME=VALUE with NAME one of {', '.join(RampsConfig.__struct_fields__)}")
        changes[name] = value
    try:
        return msgspec.convert(changes, RampsConfig, strict=False)
    except (msgspec.ValidationError, ValueError) as exc:
        fail(f"--set: {exc}")


@sim_app.command("campaign")
def sim_campaign(
    runs: int = typer.Option(1000, "--runs", "-n", min=1, help="random runs"),
    seed: int = typer.Option(0, "--seed", help="the same seed replays the same runs"),
    policy: str = typer.Option("ramps", "--policy", "-p", help=POLICY_HELP),
    load_changes: bool = typer.Option(False, "--load-changes",
                                      help="robots also start and stop busy processes of their own while programs "
                                           "run, and some programs checkpoint: relocation moves and resumes them "
                                           "in the middle of the faults"),
    as_json: bool = typer.Option(False, "--json", help="write the summary as JSON to stdout"),
    out_file: Optional[Path] = typer.Option(None, "--out", "-o", help="also save the JSON to this file"),
) -> None:
    """Random crashes, cuts, freezes and recoveries of non-origin robots; check the invariants.

    After every run: each program of a surviving origin completed exactly once, and a robot that
    recovered is used again. Exit code 1 if any run broke them (its scenario is in the JSON).
    """
    from ramps.experiments.campaign import run_campaign
    from ramps.experiments.report import print_campaign

    check_policy(policy)
    with Progress(TextColumn("campaign"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(), console=err,
                  transient=True) as progress:
        task = progress.add_task("campaign", total=runs)
        rep = run_campaign(runs, seed, policy, progress=lambda done, total: progress.update(task, completed=done),
                           load_changes=load_changes)
    emit([rep], print_campaign, as_json=as_json, out_file=out_file)
    if rep.failed_runs:
        raise typer.Exit(1)


@sim_app.command("relocation")
def sim_relocation(
    robots: int = typer.Option(3, "--robots", min=2, max=8, help="identical robots in the team"),
    cores: int = typer.Option(4, "--cores", min=1, help="cores per robot"),
    programs: int = typer.Option(8, "--programs", min=1, max=40, help="programs r1 submits at once"),
    work: float = typer.Option(60.0, "--work", min=1.0, help="work units per program (seconds on an idle core)"),
    loaded: str = typer.Option("r1", "--loaded", help="the robot whose own software gets busy"),
    busy: int = typer.Option(8, "--busy", min=0, help="busy processes it starts"),
    load_at: float = typer.Option(10.0, "--at", min=0.0, help="seconds after the submission"),
    checkpoint_every: float = typer.Option(2.0, "--checkpoint-every", min=0.1,
                                           help="seconds between checkpoints in the checkpointing variant"),
    seeds: int = typer.Option(5, "--seeds", min=1, help="simulation seeds"),
    seed: int = typer.Option(0, "--seed", help="first seed"),
    campaign: int = typer.Option(0, "--campaign", min=0,
                                 help="instead: run this many scenarios of `ramps sim campaign --load-changes` "
                                      "(faults and load changes) with relocation on and off, and compare makespans"),
    as_json: bool = typer.Option(False, "--json", help="write the results as JSON to stdout"),
    out_file: Optional[Path] = typer.Option(None, "--out", "-o", help="also save the JSON to this file"),
) -> None:
    """Load that changes after placement: one robot's own software starts busy processes while it runs programs.

    Runs relocation off, relocation on (restart elsewhere from the parameters), relocation with programs that
    checkpoint (resume elsewhere), and round robin on the same seeds, and prints each makespan against the
    hindsight optimum: the best static distribution for someone who knew the load would come.
    """
    from ramps.experiments.late_load import compare_on_campaign, run_relocation
    from ramps.experiments.report import print_relocation, print_relocation_campaign

    if campaign:
        emit([compare_on_campaign(campaign, seed)], print_relocation_campaign, as_json=as_json, out_file=out_file)
        return
    try:
        rep = run_relocation(robots=robots, cores=cores, programs=programs, work=work, loaded=loaded, busy=busy,
                             load_at=load_at, checkpoint_every=checkpoint_every, seeds=seeds, seed=seed)
    except ValueError as exc:
        fail(str(exc))
    emit([rep], print_relocation, as_json=as_json, out_file=out_file)


@sim_app.command("accelerators")
def sim_accelerators(
    scenarios: int = typer.Option(220, "--scenarios", "-n", min=1, help="generated scenarios (the kinds in turn)"),
    seed: int = typer.Option(0, "--seed", help="generates the scenarios; the same seed gives the same table"),
    exact_seconds: float = typer.Option(5.0, "--exact-seconds", min=0.1,
                                        help="CP-SAT's deterministic time per scenario to prove the optimum (about "
                                             "seconds); one that runs out is compared with its bound instead"),
    as_json: bool = typer.Option(False, "--json", help="write the results as JSON to stdout instead of tables"),
    out_file: Optional[Path] = typer.Option(None, "--out", "-o", help="also save the JSON to this file"),
) -> None:
    """Accelerators: ramps, ramps blind to them, and round robin against the CP-SAT optimum.

    Generated teams of 2-6 robots, some with 1-2 accelerator slots of speed 5-30, one to three origins
    submitting at once programs that run 1x-30x faster on a slot, CPU-only ones, ones that need a slot;
    kinds with mis-declared accelerator work and with an accelerator robot that crashes or is cut off.
    The table shows each placement's makespan over the exact optimum of the same batch (or over its bound
    where CP-SAT proves nothing in time), median and worst per kind; about a minute on two cores. A second
    table gives ramps over the optimum told only the declared accelerator work (its placement timed with
    the true work): what an origin told only the declarations could best do, a reference and not a bound.
    """
    from ramps.experiments.accelerators import print_accelerators, run_family

    with Progress(TextColumn("accelerators"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(), console=err,
                  transient=True) as progress:
        task = progress.add_task("accelerators", total=scenarios)
        rep = run_family(scenarios, seed=seed, exact_seconds=exact_seconds,
                         progress=lambda done, total: progress.update(task, completed=done))
    emit([rep], print_accelerators, as_json=as_json, out_file=out_file)


@sim_app.command("battery")
def sim_battery(
    scenarios: int = typer.Option(240, "--scenarios", "-n", min=1, help="generated scenarios"),
    seed: int = typer.Option(0, "--seed", help="generates the scenarios; the same seed gives the same table"),
    sim_seed: int = typer.Option(1, "--sim-seed", help="the simulator's seed, the same for every variant"),
    as_json: bool = typer.Option(False, "--json", help="write the results as JSON to stdout instead of tables"),
    out_file: Optional[Path] = typer.Option(None, "--out", "-o", help="also save the JSON to this file"),
) -> None:
    """Low batteries: ramps, ramps ignoring batteries, and round robin against the exact optimum.

    Generated teams of 3-5 robots of mixed cores and speeds, two or three origins submitting 2-4
    checkpointing programs each (at most 12 in all), and a robot below its battery reserve from the
    start, one that drops below it mid-run, or one that crashes. A robot below its reserve runs no
    teammate's program: the optimum is the shortest makespan of any placement that keeps to that,
    knowing every drop and crash in advance (dynamic programming over subsets). "on low" counts the
    programs a variant ran on a robot below its reserve for another origin; ramps_full is ramps on the
    same teams with every battery full, against that scenario's optimum. About a minute on two cores.
    """
    from ramps.experiments.battery import format_report, run_family

    with Progress(TextColumn("battery"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(), console=err,
                  transient=True) as progress:
        task = progress.add_task("battery", total=scenarios)
        rep = run_family(scenarios, seed=seed, sim_seed=sim_seed,
                         progress=lambda done, total: progress.update(task, completed=done))
    emit([rep], lambda r, console: console.print(format_report(r), highlight=False, soft_wrap=True),
         as_json=as_json, out_file=out_file)


@sim_app.command("energy")
def sim_energy(
    weights: str = typer.Option("0,0.1,0.2,0.3,0.4,0.5,0.6,0.7,0.8,0.9,1", "--weights", metavar="W,W,...",
                                help="energy weights to run, each 0..1 ([core] energy_weight)"),
    seeds: int = typer.Option(5, "--seeds", min=1, help="simulation seeds per weight (the medians are printed)"),
    programs: int = typer.Option(8, "--programs", min=1, help="programs each of the three origins submits"),
    work: float = typer.Option(30.0, "--work", min=0.1, help="work units per program"),
    seed: int = typer.Option(0, "--seed", help="first seed"),
    as_json: bool = typer.Option(False, "--json", help="write the curve as JSON to stdout instead of a table"),
    out_file: Optional[Path] = typer.Option(None, "--out", "-o", help="also save the JSON to this file"),
) -> None:
    """Makespan against energy as placement weighs energy ([core] energy_weight).

    A team of fast robots that burn 20 W a core, middling ones (6 W) and slow, frugal ones (2.4 W);
    three origins submit a burst each. For each weight, the median makespan and the median energy
    (busy core-seconds times watts) over the seeds, and the share of the work each kind of robot
    ran; round robin on the same seeds last. Weight 0 places for the earliest finish, 1 for the
    fewest joules per unit of work.
    """
    from ramps.experiments.energy import format_report, run_curve

    try:
        ws = [float(w) for w in weights.split(",") if w.strip()]
    except ValueError:
        fail(f"--weights takes numbers 0..1 separated by commas, got {weights!r}")
    if not ws or any(not 0.0 <= w <= 1.0 for w in ws):
        fail(f"--weights takes numbers 0..1 separated by commas, got {weights!r}")
    with Progress(TextColumn("energy"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(), console=err,
                  transient=True) as progress:
        task = progress.add_task("energy", total=(len(ws) + 1) * seeds)
        rep = run_curve(ws, seeds=seeds, programs=programs, work=work, seed=seed,
                        progress=lambda done, total: progress.update(task, completed=done))
    emit([rep], lambda r, console: console.print(format_report(r), highlight=False, soft_wrap=True),
         as_json=as_json, out_file=out_file)


@sim_app.command("run")
def sim_run(
    scenario: Path = typer.Argument(..., help="scenario file (YAML or TOML); see examples/ and examples/README.md"),
    policy: Optional[str] = typer.Option(None, "--policy", "-p", help=POLICY_HELP + " (default: the file's)"),
    seed: Optional[int] = typer.Option(None, "--seed", help="override the file's seed"),
    as_json: bool = typer.Option(False, "--json", help="write the full result as JSON to stdout"),
    trace: bool = typer.Option(False, "--trace", help="include every decision (placements, failures) in the JSON"),
    out_file: Optional[Path] = typer.Option(None, "--out", "-o", help="also save the JSON to this file"),
) -> None:
    """Simulate your own team and workload described in a scenario file."""
    from ramps.experiments.report import print_sim_result
    from ramps.sim.engine import simulate
    from ramps.sim.scenario_file import ScenarioFileError, load_scenario

    if policy is not None:
        check_policy(policy)
    try:
        sc = load_scenario(scenario)
    except ScenarioFileError as exc:
        fail(str(exc))
    if not as_json:
        err.print(f"simulating {scenario} ({len(sc.team())} robots, "
                  f"{sum(p.count for p in sc.programs)} programs) ...")
    res = simulate(sc, policy=policy, seed=seed, trace=trace)
    emit([res], print_sim_result, as_json=as_json, out_file=out_file)
    if res.lost or res.duplicated:
        raise typer.Exit(1)

