"""The ``ramps`` command.

Rules: the CLI parses, calls the library, prints. User mistakes (a bad
scenario file, an unknown policy) end with a one-line message and exit code
2, never a traceback. Long work shows progress on stderr so ``--json`` output
on stdout stays clean for scripts.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Optional

import msgspec
import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from ramps import __version__

app = typer.Typer(
    help="ramps: share computational work across a robot team, with no central scheduler, "
    "and keep it alive when robots fail (Reliable Autonomous Mobile Programs).",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
sim_app = typer.Typer(help="Simulate teams and workloads in virtual time (seconds for hours of robot time).",
                      no_args_is_help=True)
bench_app = typer.Typer(help="Benchmarks that print figures and save them as JSON.", no_args_is_help=True)
app.add_typer(sim_app, name="sim")
app.add_typer(bench_app, name="bench")
from ramps.cli_team import team_app  # noqa: E402  (ramps team init/add)
app.add_typer(team_app, name="team")
from ramps.cli_observe import register as _register_observe  # noqa: E402  (ramps report/top, bench metrics)
_register_observe(app, bench_app)
from ramps.ros.cli import register as _register_ros  # noqa: E402  (ramps ros; rclpy only when it runs)
_register_ros(app)

# a pipe or a CI log gets wide tables instead of wrapped ones
out = Console(width=None if sys.stdout.isatty() else 200)
err = Console(stderr=True)

POLICY_HELP = "placement policy: ramps (default, ours), paper (faithful to the paper), round_robin, random, local_only"
DISCOVERY_HELP = ("how testbed robots find each other: both (multicast plus a seed robot), multicast, "
                  "or connect (explicit endpoints only)")


def fail(message: str, code: int = 2) -> None:
    err.print(f"[bold red]error:[/] {message}", highlight=False, soft_wrap=True)
    raise typer.Exit(code)


def _check_policy(policy: str) -> None:
    from ramps.core.policy import POLICIES

    if policy not in POLICIES:
        fail(f"unknown policy {policy!r}; choose one of {', '.join(POLICIES)}")


def _check_discovery(discovery: str) -> None:
    if discovery not in ("both", "multicast", "connect"):
        fail(f"unknown discovery {discovery!r}; choose both, multicast or connect")


def _emit(reports: list, printer, *, as_json: bool, out_file: Optional[Path]) -> None:
    """Print results as tables (``printer(report, console)`` for each) or as
    JSON on stdout (one report, or ``{"experiments": [...]}``), and save the
    JSON to ``out_file`` too when given."""
    data = msgspec.json.encode(reports[0] if len(reports) == 1 else {"experiments": reports})
    if as_json:
        sys.stdout.write(data.decode() + "\n")
    else:
        for rep in reports:
            printer(rep, out)
    if out_file is not None:
        _save_json(data, out_file)
        err.print(f"wrote {out_file}")


def _save_json(data: bytes, out_file: Path) -> None:
    out_file.parent.mkdir(parents=True, exist_ok=True)
    out_file.write_bytes(data + b"\n")


@app.command()
def version() -> None:
    """Print the ramps version."""
    out.print(f"ramps {__version__}")


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

    _check_policy(policy)
    if plot is not None:
        from ramps.cli_observe import sim_paper_plot

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
            reports.append(run_experiment(e, policy=policy, runs=runs, seed=seed,
                                          progress=lambda done, total, t=task: progress.update(t, completed=done)))
    _emit(reports, print_experiment, as_json=as_json, out_file=out_file)


def _sim_faults(mode: str, kind: str, *, policy: str, runs: int, seed: int, as_json: bool,
                out_file: Optional[Path]) -> None:
    from ramps.experiments.faults import KINDS, run_fault_experiment
    from ramps.experiments.report import print_fault_report

    modes = ["sequential", "simultaneous"] if mode == "all" else [mode]
    kinds = list(KINDS) if kind == "all" else [kind]
    if any(m not in ("sequential", "simultaneous") for m in modes):
        fail(f"unknown mode {mode!r}; choose sequential, simultaneous or all")
    if any(k not in KINDS for k in kinds):
        fail(f"unknown kind {kind!r}; choose crash, network, mixed or all")
    reports = [run_fault_experiment(m, k, policy=policy, runs=runs, seed=seed) for m in modes for k in kinds]
    _emit(reports, print_fault_report, as_json=as_json, out_file=out_file)
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
    omniscient central scheduler; the default sweep (216 scenarios x 3
    seeds) takes a few minutes.
    """
    from ramps.experiments.report import print_sweep
    from ramps.experiments.sweep import FAMILIES, TEAMS, TIMINGS, run_sweep

    _check_policy(policy)
    if family not in FAMILIES:
        fail(f"unknown family {family!r}; choose multi-origin or one of "
             + ", ".join(f"{t}-{s}" for t in TEAMS for s in TIMINGS))
    config = _config_with(settings) if settings else None
    total = scenarios * len(FAMILIES[family])
    with Progress(TextColumn(f"sweep {family} / {policy}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                  console=err, transient=True) as progress:
        task = progress.add_task("sweep", total=total)
        rep = run_sweep(family, per_family=scenarios, seeds=seeds, seed=seed, policy=policy, config=config,
                        progress=lambda done, total: progress.update(task, completed=done))
    _emit([rep], print_sweep, as_json=as_json, out_file=out_file)


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
    as_json: bool = typer.Option(False, "--json", help="write the summary as JSON to stdout"),
    out_file: Optional[Path] = typer.Option(None, "--out", "-o", help="also save the JSON to this file"),
) -> None:
    """Random crashes, cuts, freezes and recoveries of non-origin robots; check the invariants.

    After every run: each program of a surviving origin completed exactly once, and a robot that
    recovered is used again. Exit code 1 if any run broke them (its scenario is in the JSON).
    """
    from ramps.experiments.campaign import run_campaign
    from ramps.experiments.report import print_campaign

    _check_policy(policy)
    with Progress(TextColumn("campaign"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(), console=err,
                  transient=True) as progress:
        task = progress.add_task("campaign", total=runs)
        rep = run_campaign(runs, seed, policy, progress=lambda done, total: progress.update(task, completed=done))
    _emit([rep], print_campaign, as_json=as_json, out_file=out_file)
    if rep.failed_runs:
        raise typer.Exit(1)


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
        _check_policy(policy)
    try:
        sc = load_scenario(scenario)
    except ScenarioFileError as exc:
        fail(str(exc))
    if not as_json:
        err.print(f"simulating {scenario} ({len(sc.team())} robots, "
                  f"{sum(p.count for p in sc.programs)} programs) ...")
    res = simulate(sc, policy=policy, seed=seed, trace=trace)
    _emit([res], print_sim_result, as_json=as_json, out_file=out_file)
    if res.lost or res.duplicated:
        raise typer.Exit(1)


@bench_app.command("sim")
def bench_sim(
    runs: int = typer.Option(3, "--runs", "-n", min=1, help="runs per configuration in the sweep"),
    robots: int = typer.Option(1000, "--robots", min=1, help="robots in the large scenario"),
    programs: int = typer.Option(10_000, "--programs", min=1, help="programs in the large scenario"),
    origins: int = typer.Option(10, "--origins", min=1, help="robots that submit programs in the large scenario"),
    out_file: Path = typer.Option(Path("bench-results/sim.json"), "--out", "-o", help="where to save the JSON"),
) -> None:
    """Time the full paper sweep and a large-team scenario."""
    from ramps.experiments.bench import bench_large, bench_sweep, machine

    if origins > robots:
        fail("--origins cannot exceed --robots")
    err.print(f"sweep: unloaded + loaded, {runs} run(s) each, 3 simulations per run ...")
    sweep = bench_sweep(runs)
    out.print(f"paper sweep (unloaded + loaded, {runs} runs each): {sweep['wall_seconds']:.2f} s "
              f"({sweep['unloaded']['simulations'] + sweep['loaded']['simulations']} simulations)")
    err.print(f"large team: {robots} robots, {programs} programs from {origins} origins ...")
    large = bench_large(robots, programs, origins)
    out.print(f"large team ({robots} robots, {programs} programs): {large['wall_seconds']:.2f} s wall, "
              f"{large['events']} events ({large['events_per_s']:.0f}/s), completed {large['completed']}, "
              f"lost {large['lost']}, duplicated {large['duplicated']}, virtual makespan "
              f"{large['makespan_virtual_s']:.1f} s")
    result = {"benchmark": "sim", "machine": machine(), "sweep": sweep, "large": large}
    out_file.parent.mkdir(parents=True, exist_ok=True)
    out_file.write_text(json.dumps(result, indent=2) + "\n")
    out.print(f"saved {out_file}")


@bench_app.command("dispatch")
def bench_dispatch_cmd(
    nodes: int = typer.Option(3, "--nodes", min=1, help="real node processes on loopback"),
    calls: int = typer.Option(1000, "--calls", min=10, help="sequential calls timed for latency"),
    burst: int = typer.Option(5000, "--burst", min=10, help="calls for the throughput figure"),
    window: int = typer.Option(256, "--window", min=1, help="calls in flight at most during the burst"),
    out_file: Path = typer.Option(Path("bench-results/dispatch.json"), "--out", "-o", help="where to save the JSON"),
) -> None:
    """Latency from submit to result of a no-op program on a real loopback team, and throughput."""
    from ramps.experiments.dispatch import bench_dispatch

    err.print(f"starting {nodes} nodes on loopback; {calls} sequential calls, then {burst} with {window} in flight ...")
    res = bench_dispatch(nodes=nodes, calls=calls, burst=burst, window=window)
    out.print(f"dispatch latency (submit -> result, {res['calls']} no-op calls): p50 {res['p50_ms']:.2f} ms, "
              f"p90 {res['p90_ms']:.2f} ms, p99 {res['p99_ms']:.2f} ms, max {res['max_ms']:.1f} ms; "
              f"ran on {res['latency_hosts']}")
    out.print(f"offloaded to another robot ({res['remote_calls']} calls): p50 {res['remote_p50_ms']:.2f} ms, "
              f"p99 {res['remote_p99_ms']:.2f} ms")
    out.print(f"throughput from one origin: {res['throughput_per_s']:.0f} programs/s "
              f"({res['completed']}/{res['burst']} completed; ran on {res['burst_hosts']})")
    out_file.parent.mkdir(parents=True, exist_ok=True)
    out_file.write_text(json.dumps(res, indent=2) + "\n")
    out.print(f"saved {out_file}")


@bench_app.command("fuzz")
def bench_fuzz_cmd(
    inputs: int = typer.Option(100_000, "--inputs", "-n", min=1, help="generated inputs in all"),
    seed: int = typer.Option(0, "--seed", help="seed of the input generator (same seed, same inputs)"),
    as_json: bool = typer.Option(False, "--json", help="print the figures as JSON"),
    out_file: Path = typer.Option(Path("bench-results/fuzz.json"), "--out", "-o", help="where to save the JSON"),
) -> None:
    """Garbage, mutated and hostile messages at the wire decoder, the argument decoder and the core (exit 1 on any unhandled exception)."""
    from ramps.experiments.fuzz import run_fuzz

    err.print(f"fuzzing with {inputs} inputs, seed {seed} ...")
    res = run_fuzz(inputs=inputs, seed=seed, progress=lambda n: err.print(f"  {n} inputs", highlight=False))

    def show(r, console) -> None:
        console.print(f"fuzz: {r['inputs']} inputs in {r['seconds']:.2f} s ({r['inputs_per_s']:.0f}/s), "
                      f"seed {r['seed']}: {r['decoder_inputs']} at the wire decoder ({r['decoded']} decoded, "
                      f"{r['wire_errors']} refused), {r['args_inputs']} at the argument decoder, "
                      f"{r['core_events']} core events (+{r['core_from_decoder']} decoded messages) on "
                      f"{r['core_nodes']} nodes, {r['programs_delivered']} programs delivered; "
                      f"unhandled exceptions: {r['exceptions']}", highlight=False)
        for x in r["exception_samples"]:
            console.print(f"  {x['target']} ({x['kind']}): {x['error']}", highlight=False)

    _emit([res], show, as_json=as_json, out_file=out_file)
    if res["exceptions"]:
        raise typer.Exit(1)


@bench_app.command("flood")
def bench_flood_cmd(
    messages: int = typer.Option(10_000, "--messages", "-n", min=1, help="malformed messages to send"),
    seconds: float = typer.Option(10.0, "--seconds", min=0.1, help="over how long"),
    programs: int = typer.Option(40, "--programs", min=1, help="legitimate programs run during the flood"),
    seed: int = typer.Option(0, "--seed", help="seed of the malformed messages"),
    as_json: bool = typer.Option(False, "--json", help="print the figures as JSON"),
    out_file: Path = typer.Option(Path("bench-results/flood.json"), "--out", "-o", help="where to save the JSON"),
) -> None:
    """Flood a real node with malformed and oversized messages while it runs programs: drops counted, memory, programs completed."""
    from ramps.experiments.flood import bench_flood

    err.print(f"starting 2 nodes on loopback; flooding r1 with {messages} messages over {seconds:g} s ...")
    res = bench_flood(messages=messages, seconds=seconds, programs=programs, seed=seed)

    def show(r, console) -> None:
        mb = 1 << 20
        console.print(f"flood: sent {r['messages_sent']} malformed messages ({r['big_messages']} of 1-9 MB, "
                      f"{r['bytes_sent'] / mb:.0f} MB) in {r['flood_seconds']:.1f} s ({r['send_rate_per_s']:.0f}/s); "
                      f"dropped and counted by r1: {r['dropped_counted']['r1']} of {r['expected_at_target']}, "
                      f"by r2 (load key only): {r['dropped_counted']['r2']} of {r['expected_at_others']}",
                      highlight=False)
        console.print(f"programs: {r['programs_ok']}/{r['programs']} completed correctly "
                      f"({r['programs_failed']} failed, {r['programs_wrong']} wrong) on {r['program_hosts']}; "
                      f"r1 resident memory {r['rss_before_mb']['r1']:.1f} MB before, peak {r['rss_peak_mb']:.1f} MB, "
                      f"{r['rss_after_mb']['r1']:.1f} MB after (growth {r['rss_growth_mb']['r1']:+.1f} MB); "
                      f"alive: {r['alive']}", highlight=False)
        for f in r["failures"]:
            console.print(f"  {f}", highlight=False)

    _emit([res], show, as_json=as_json, out_file=out_file)
    if res["programs_ok"] != res["programs"] or not all(res["alive"].values()):
        raise typer.Exit(1)


# ====================================================================== the real team
def _settings(**flags):
    from ramps.errors import ConfigError
    from ramps.runtime.settings import load_settings

    config_file = flags.pop("config_file", None)
    default_robot = flags.pop("default_robot", True)
    try:
        return load_settings(config_file=config_file, flags=flags, default_robot=default_robot)
    except ConfigError as exc:
        fail(str(exc))


TEAM_HELP = "team name: teams on one network never hear each other (env RAMPS_TEAM)"
SECURE_HELP = "secured team: TLS links, team certificates, access control (env RAMPS_SECURE; see `ramps team`)"
CREDENTIALS_HELP = "this robot's credentials directory from `ramps team add` (env RAMPS_CREDENTIALS)"
CONNECT_HELP = "Zenoh endpoint of a teammate, e.g. tcp/192.168.1.12:7447 (repeatable; env RAMPS_CONNECT)"


@app.command()
def node(
    robot: Optional[str] = typer.Option(None, "--robot", "-r", help="this robot's name (default: host name; env RAMPS_ROBOT)"),
    team: Optional[str] = typer.Option(None, "--team", "-t", help=TEAM_HELP),
    listen: Optional[list[str]] = typer.Option(None, "--listen", "-l", help="Zenoh endpoint to listen on (repeatable; default tcp/0.0.0.0:0)"),
    connect: Optional[list[str]] = typer.Option(None, "--connect", "-c", help=CONNECT_HELP),
    multicast: Optional[bool] = typer.Option(None, "--multicast/--no-multicast", help="find teammates by UDP multicast (default on)"),
    cores: Optional[int] = typer.Option(None, "--cores", min=1, help="cores offered to programs (default: detected)"),
    speed: Optional[float] = typer.Option(None, "--speed", help="work units per second per core (default: measured)"),
    policy: Optional[str] = typer.Option(None, "--policy", "-p", help=POLICY_HELP),
    program: Optional[list[str]] = typer.Option(None, "--program", help="extra program as package.module:function (repeatable)"),
    command: Optional[list[str]] = typer.Option(None, "--command", help="an executable as a program, NAME=PATH (repeatable; env RAMPS_COMMANDS): "
                                                "arguments as a JSON object on stdin, result as JSON on stdout, failure = non-zero exit "
                                                "(stderr tail returned), progress = 'RAMPS_PROGRESS 0.4' lines on stderr, killed with its "
                                                "process group when withdrawn or after 600 s ([commands.NAME] timeout in --config)"),
    config_file: Optional[Path] = typer.Option(None, "--config", help="TOML config file (env RAMPS_CONFIG)"),
    lease_ms: Optional[int] = typer.Option(None, "--lease-ms", help="Zenoh session lease: how fast a frozen or cut-off peer is noticed"),
    trace: Optional[Path] = typer.Option(None, "--trace", help="write every placement, failure and delivery decision to this file (JSON lines)"),
    secure: bool = typer.Option(False, "--secure", help=SECURE_HELP),
    credentials: Optional[Path] = typer.Option(None, "--credentials", help=CREDENTIALS_HELP),
    metrics: Optional[str] = typer.Option(None, "--metrics", help="serve Prometheus metrics on ADDR:PORT, e.g. "
                                          "127.0.0.1:9464 or 0.0.0.0:9464 for a Prometheus elsewhere (default off; "
                                          "env RAMPS_METRICS)"),
    verbose: bool = typer.Option(False, "--verbose", "-v", help="log every blacklisting and failure"),
) -> None:
    """Run this robot's ramps node until Ctrl-C: load publisher, load server, program executor.

    On shutdown (Ctrl-C, SIGTERM) running programs are handed back to their origins, which
    place them elsewhere at once.
    """
    import logging

    from rich.logging import RichHandler

    from ramps.errors import RampsError
    from ramps.runtime.node import NodeRuntime

    logging.basicConfig(level=logging.INFO if verbose else logging.WARNING, format="%(message)s",
                        handlers=[RichHandler(console=err, show_path=False)])
    if policy is not None:
        _check_policy(policy)
    commands = None
    if command:
        from ramps.errors import ConfigError
        from ramps.runtime.settings import parse_commands

        try:
            commands = {k: msgspec.to_builtins(v) for k, v in parse_commands(command).items()}
        except (ConfigError, ValueError) as exc:
            fail(str(exc))
    s = _settings(robot=robot, commands=commands, team=team, listen=listen or None, connect=connect or None, multicast=multicast,
                  cores=cores, speed=speed, policy=policy, programs=program or None, config_file=config_file,
                  lease_ms=lease_ms, trace=str(trace) if trace else None, secure=secure or None,
                  credentials=str(credentials) if credentials else None, metrics=metrics)
    import signal
    import threading

    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    try:
        rt = NodeRuntime(s).start()
    except RampsError as exc:
        fail(str(exc))
    err.print(f"[bold]ramps node {rt.robot}[/] joined team [bold]{rt.team}[/]: {rt.cores} cores, speed {rt.speed:g}, "
              f"policy {s.policy}, load measured on the {rt.load_scope}; listening on {', '.join(s.listen_endpoints())}"
              + (f"; connecting to {', '.join(s.connect)}" if s.connect else "")
              + ("; multicast discovery on" if s.multicast else "")
              + ("; secured: TLS with team certificates" if s.secure else "")
              + (f"; metrics on http://{rt.metrics.address[0]}:{rt.metrics.address[1]}/metrics" if rt.metrics else ""),
              highlight=False, soft_wrap=True)
    err.print(f"programs: {', '.join(sorted(rt.registry.names()))}. Ctrl-C to leave the team.", highlight=False,
              soft_wrap=True)
    try:
        while not stop.wait(0.5) and not rt.wait(0):
            pass
    finally:
        err.print(f"ramps node {rt.robot}: leaving the team, handing running programs back ...")
        rt.stop()
    if rt.revoked_self:
        fail(f"robot {rt.robot} was revoked by team {rt.team} (revocation list {rt.revocations.seq}): it left the team")


def _parse_arg(text: str) -> tuple[str, object]:
    key, sep, raw = text.partition("=")
    if not sep or not key.isidentifier():
        fail(f"--arg must look like name=value, got {text!r}")
    try:
        return key, json.loads(raw)
    except json.JSONDecodeError:
        return key, raw


def _connect_team(team, robot, connect, multicast, timeout, config_file=None, secure=None, credentials=None):
    from ramps.errors import RampsError
    from ramps.runtime.client import Team

    s = _settings(team=team, connect=connect or None, multicast=multicast, config_file=config_file,
                  default_robot=False, secure=secure or None, credentials=str(credentials) if credentials else None)
    try:
        return Team(s, robot=robot, timeout=timeout)
    except RampsError as exc:
        fail(str(exc))


@app.command()
def submit(
    program: str = typer.Argument(..., help="registered program name, e.g. route_plan, burn, echo"),
    arg: Optional[list[str]] = typer.Option(None, "--arg", "-a", help="argument name=value (JSON values: 3, 2.5, true, [1,2]); repeatable"),
    team: Optional[str] = typer.Option(None, "--team", "-t", help=TEAM_HELP),
    robot: Optional[str] = typer.Option(None, "--robot", "-r", help="node that is the origin (default: this host's, or any)"),
    connect: Optional[list[str]] = typer.Option(None, "--connect", "-c", help=CONNECT_HELP),
    multicast: Optional[bool] = typer.Option(None, "--multicast/--no-multicast", help="find the team by UDP multicast"),
    count: int = typer.Option(1, "--count", "-n", min=1, help="submit the same call this many times"),
    timeout: Optional[float] = typer.Option(None, "--timeout", help="give up (and withdraw the program) after this many seconds"),
    as_json: bool = typer.Option(False, "--json", help="print results as JSON lines"),
    progress: bool = typer.Option(False, "--progress", help="print each program's placement, host and progress "
                                  "on stderr as it changes"),
    secure: bool = typer.Option(False, "--secure", help=SECURE_HELP),
    credentials: Optional[Path] = typer.Option(None, "--credentials", help=CREDENTIALS_HELP),
) -> None:
    """Run a program on the team and print its result."""
    import time as _time

    from ramps.errors import RampsError

    args = dict(_parse_arg(a) for a in arg or [])
    t = _connect_team(team, robot, connect, multicast, 5.0, secure=secure, credentials=credentials)
    try:
        started = _time.perf_counter()
        try:
            futs = [t.options(timeout=timeout).submit(program, **args) for _ in range(count)]
            if progress:
                for i, f in enumerate(futs):
                    f.add_update_callback(lambda f, i=i: None if f.done() else err.print(
                        f"[{i + 1}/{count}] {f.program}: {f.state} on {f.host or '?'}"
                        + ("" if f.progress is None else f" {100 * f.progress:.0f}% {f.progress_detail}"),
                        highlight=False, soft_wrap=True))
        except RampsError as exc:
            fail(str(exc))
        code = 0
        for f in futs:
            try:
                value = f.result()
                line = {"ok": True, "value": value}
            except (RampsError, TimeoutError) as exc:
                code = 1
                line = {"ok": False, "error": f"{type(exc).__name__}: {exc}"}
            if as_json:
                sys.stdout.write(json.dumps(line, default=str) + "\n")
            elif line["ok"]:
                out.print(line["value"])
            else:
                err.print(f"[red]{line['error']}[/]", highlight=False, soft_wrap=True)
        if not as_json:
            err.print(f"{count} program(s) in {_time.perf_counter() - started:.2f} s via {t.robot}")
    finally:
        t.close()
    raise typer.Exit(code)


@app.command()
def status(
    team: Optional[str] = typer.Option(None, "--team", "-t", help=TEAM_HELP),
    connect: Optional[list[str]] = typer.Option(None, "--connect", "-c", help=CONNECT_HELP),
    multicast: Optional[bool] = typer.Option(None, "--multicast/--no-multicast", help="find the team by UDP multicast"),
    wait: float = typer.Option(2.5, "--wait", help="seconds to listen for load reports"),
    secure: bool = typer.Option(False, "--secure", help=SECURE_HELP),
    credentials: Optional[Path] = typer.Option(None, "--credentials", help=CREDENTIALS_HELP),
    as_json: bool = typer.Option(False, "--json", help="print the team view as JSON"),
) -> None:
    """Show the team: robots, their load, running programs, blacklisted peers.

    Each row is what that robot last published. "sees" is how many teammates
    the robot itself could place a program on (fresh report, not written
    off): a robot that sees fewer than the rest is cut off from part of the
    team, even when this command sees everyone."""
    import time as _time

    from rich.table import Table

    t = _connect_team(team, None, connect, multicast, 5.0, secure=secure, credentials=credentials)
    try:
        _time.sleep(wait)
        st = t.status()
    finally:
        t.close()
    if as_json:
        sys.stdout.write(msgspec.json.encode(st).decode() + "\n")
        return
    table = Table(title=f"team {st.team}", title_justify="left")
    for name in ("robot", "alive", "cores", "speed", "cpu busy", "per core %", "run queue", "load avg", "mem free",
                 "programs", "done", "dropped msgs", "sees", "blacklists", "report age"):
        table.add_column(name, justify="left" if name in ("robot", "blacklists", "per core %") else "right")
    for r in st.robots:
        table.add_row(r.robot, "yes" if r.alive else "[red]no[/]", str(r.cores), f"{r.speed:g}", f"{r.cpu_busy:.2f}",
                      " ".join(f"{100 * c:.0f}" for c in r.cpu_per_core[:16]), f"{r.runnable:.1f}",
                      f"{r.load_avg:.2f}", f"{r.mem_free / 2**30:.1f} GiB", str(r.ramps_running),
                      str(r.finished_total), str(r.bad_messages), "-" if r.sees is None else str(r.sees),
                      ", ".join(r.blacklisted),
                      "-" if r.report_age is None else f"{r.report_age:.1f} s")
    out.print(table)
    running = [(r.robot, p) for r in st.robots for p in r.running]
    if running:
        progs = Table(title="running programs", title_justify="left")
        for name in ("host", "program", "origin", "progress"):
            progs.add_column(name, justify="right" if name == "progress" else "left")
        for host, p in running:
            progs.add_row(host, p.program, p.origin, "-" if p.progress is None else f"{100 * p.progress:.0f}%")
        out.print(progs)


@app.command()
def demo(
    robots: int = typer.Option(5, "--robots", "-n", min=2, max=16, help="robots in the team (real node processes)"),
    programs: int = typer.Option(15, "--programs", "-p", min=1, help="route-planning programs submitted from r1"),
    size: str = typer.Option("demo", "--size", help="route-planning instance: demo (~1.4 CPU s each), tiny, small, medium, large"),
    loaded: Optional[list[str]] = typer.Option(None, "--loaded", help="robot that also runs 8 busy processes, e.g. r5 (repeatable)"),
    kill: Optional[str] = typer.Option(None, "--kill", help="robot to SIGKILL during the ramps run, e.g. r3"),
    kill_at: float = typer.Option(3.0, "--kill-at", help="seconds into the ramps run when --kill strikes"),
    shared: bool = typer.Option(False, "--shared", help="no cgroups: the nodes share this machine's cores"),
    as_json: bool = typer.Option(False, "--json", help="print the report as JSON"),
    report: Path = typer.Option(Path("ramps-demo-report.html"), "--report", help="where to save the HTML report "
                                "of the ramps run (timeline, load, distribution; the nodes' trace beside it)"),
) -> None:
    """The main job: a team of real nodes on this machine runs the paper's scenario.

    Starts the team, has robot r1 submit 15 route-planning programs, shows progress, then
    prints the distribution per robot and the makespan, next to the same job placed by round
    robin and run on r1 alone, in the same session. With root, each robot is its own cpu cgroup
    (an equal share of this host), so the team really is several small computers.
    """
    from rich.progress import Progress as _Progress
    from rich.table import Table

    from ramps.experiments.demo import DEMO_ROUTE, run_demo
    from ramps.programs.route import ROUTE_SIZES

    sizes = {"demo": DEMO_ROUTE, **ROUTE_SIZES}
    if size not in sizes:
        fail(f"unknown size {size!r}; choose one of {', '.join(sizes)}")
    progress = _Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                         TextColumn("{task.fields[spread]}"), console=err, transient=not as_json)
    tasks: dict[str, int] = {}

    def on_progress(phase: str, done: int, total: int, dist) -> None:
        if phase not in tasks:
            tasks[phase] = progress.add_task(phase, total=total, spread="")
        spread = " ".join(f"{r}:{k}" for r, k in sorted(dist.items()))
        progress.update(tasks[phase], completed=done, spread=spread)

    err.print(f"starting a team of {robots} robots on this machine ...")
    try:
        with progress:
            rep = run_demo(robots=robots, programs=programs, arguments=dict(sizes[size]), loaded=loaded or [],
                           kill=kill, kill_at=kill_at, emulate=False if shared else None, on_progress=on_progress,
                           report=str(report))
    except (ValueError, PermissionError) as exc:
        fail(str(exc))
    if as_json:
        sys.stdout.write(msgspec.json.encode(rep).decode() + "\n")
        return
    out.print(f"[bold]mode:[/] {rep.mode}", highlight=False)
    extra = []
    if rep.loaded:
        extra.append(f"loaded: {', '.join(rep.loaded)} (8 busy processes each)")
    if rep.killed:
        extra.append(f"{rep.killed} was SIGKILLed during the ramps run and restarted for the baselines")
    out.print(f"workload: {rep.programs} x {rep.program}({', '.join(f'{k}={v}' for k, v in rep.arguments.items())}, "
              f"start=one of the {rep.programs} free cells nearest the robot) from r1" + ("; " + "; ".join(extra) if extra else ""), highlight=False)
    table = Table(title_justify="left")
    table.add_column("placement")
    for r in rep.robots:
        table.add_column(r + ("*" if r in rep.loaded else ""), justify="right")
    table.add_column("makespan", justify="right")
    table.add_column("vs 1 robot", justify="right")
    single = rep.phases[-1].makespan
    for ph in rep.phases:
        row = [ph.name] + [str(ph.distribution.get(r, 0)) for r in rep.robots]
        row += [f"{ph.makespan:.1f} s", f"{single / ph.makespan:.2f}x"]
        table.add_row(*row)
    out.print(table)
    ramps_phase = rep.phases[0]
    out.print(f"ramps: {rep.speedup_vs_single:.2f}x faster than one robot, {1 / rep.ratio_to_round_robin:.2f}x round "
              f"robin's speed; {ramps_phase.replaced} program(s) re-placed after a failure, "
              f"{sum(p.failed for p in rep.phases)} failed; {rep.wall_seconds:.0f} s in all")
    for ph in rep.phases:
        for e in ph.errors[:3]:
            err.print(f"[red]{ph.name}: {e}[/]", highlight=False, soft_wrap=True)
    if rep.report:
        out.print(f"report of the ramps run: {rep.report} (open it in a browser); the nodes' trace of the whole "
                  f"session, warm-up and baselines included: {rep.trace} (`ramps report {rep.trace}`)",
                  highlight=False, soft_wrap=True)


# ====================================================================== testbed (emulated robots)
# One block, kept apart: `ramps testbed up|status|crash|cut|freeze|recover|down`.
testbed_app = typer.Typer(help="Emulated robots on this Linux host (root): one network namespace and cpu cgroup "
                          "per robot, with fault injection.", no_args_is_help=True)
app.add_typer(testbed_app, name="testbed")
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
    lease_ms: Optional[int] = typer.Option(None, "--lease-ms", help="Zenoh lease of every node, ms"),
    policy: Optional[str] = typer.Option(None, "--policy", "-p", help=POLICY_HELP),
    program: Optional[list[str]] = typer.Option(None, "--program", help="extra program as package.module:function (repeatable)"),
    discovery: str = typer.Option("both", "--discovery", help=DISCOVERY_HELP),
    caps: bool = typer.Option(True, "--caps/--no-caps", help="cap every program (and busy process) at its processor-sharing share of the robot (cgroup v1)"),
) -> None:
    """Start a testbed and leave it running; prints the robots and how to connect."""
    from ramps.errors import RampsError
    from ramps.testbed import Testbed

    if policy is not None:
        _check_policy(policy)
    _check_discovery(discovery)
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


def _tb_fault(kind: str, robot: str, tb, *args) -> None:
    from ramps.errors import RampsError
    from ramps.testbed.net import NetError

    bed = _tb_attach(tb)
    try:
        res = getattr(bed, kind)(robot, *args)
    except (RampsError, NetError, ValueError) as exc:
        fail(str(exc))
    done = {"crash": "crashed (SIGKILL)", "cut": "cut off (link down)", "freeze": "frozen (SIGSTOP)"}
    if kind == "recover":
        out.print(f"{robot}: recovered ({', '.join(res) or 'nothing to undo'}); alive in team {bed.team}")
    elif kind == "lossy":
        out.print(f"{robot}: {args[0]:.0%} packet loss" if args[0] else f"{robot}: loss removed", highlight=False)
    else:
        out.print(f"{robot}: {done[kind]}")


@testbed_app.command("crash")
def testbed_crash(robot: str = typer.Argument(..., help="robot, e.g. r3"),
                  tb: Optional[str] = typer.Option(None, "--tb", help=TB_HELP)) -> None:
    """SIGKILL a robot's node, workers and load."""
    _tb_fault("crash", robot, tb)


@testbed_app.command("cut")
def testbed_cut(robot: str = typer.Argument(..., help="robot, e.g. r3"),
                tb: Optional[str] = typer.Option(None, "--tb", help=TB_HELP)) -> None:
    """Take a robot's network link down (it keeps computing)."""
    _tb_fault("cut", robot, tb)


@testbed_app.command("freeze")
def testbed_freeze(robot: str = typer.Argument(..., help="robot, e.g. r3"),
                   tb: Optional[str] = typer.Option(None, "--tb", help=TB_HELP)) -> None:
    """SIGSTOP every process of a robot."""
    _tb_fault("freeze", robot, tb)


@testbed_app.command("recover")
def testbed_recover(robot: str = typer.Argument(..., help="robot, e.g. r3"),
                    tb: Optional[str] = typer.Option(None, "--tb", help=TB_HELP)) -> None:
    """Undo a robot's faults: link up, SIGCONT, restart a crashed node; waits until it is alive."""
    _tb_fault("recover", robot, tb)


@testbed_app.command("lossy")
def testbed_lossy(robot: str = typer.Argument(..., help="robot, e.g. r3"),
                  loss: float = typer.Argument(..., min=0.0, max=1.0, help="drop probability of each packet, 0-1 (0 ends it)"),
                  tb: Optional[str] = typer.Option(None, "--tb", help=TB_HELP)) -> None:
    """Make a robot's link lossy (a poor WiFi link): each packet in and out is dropped with this probability."""
    _tb_fault("lossy", robot, tb, loss)


experiment_app = typer.Typer(help="The paper's experiments on real processes (each run starts its own testbed).",
                             no_args_is_help=True)
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
    discovery: str = typer.Option("both", "--discovery", help=DISCOVERY_HELP),
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

    _check_policy(policy)
    modes = ["sequential", "simultaneous"] if mode == "all" else [mode]
    kinds = list(KINDS) if kind == "all" else [kind]
    if any(m not in ("sequential", "simultaneous") for m in modes):
        fail(f"unknown mode {mode!r}; choose sequential, simultaneous or all")
    if any(k not in KINDS for k in kinds):
        fail(f"unknown kind {kind!r}; choose crash, network, mixed or all")
    total = sum(len(plans(m, k, first=gap, gap=gap)) for m in modes for k in kinds) * runs
    err.print(f"{total} testbed run(s); each takes {gap * 5:g}+ s plus the time the survivors need to finish")
    _check_discovery(discovery)
    runner = partial(run_plan, work=work, lease_ms=lease_ms, keep_logs=keep_logs, discovery=discovery,
                     log=lambda m: err.print(m, highlight=False))
    reports = []
    try:
        for m in modes:
            for k in kinds:
                reports.append(run_fault_experiment(m, k, policy=policy, runs=runs, runner=runner, first=gap, gap=gap,
                                                    world="testbed"))
                if out_file is not None and len(modes) * len(kinds) > 1:  # a long run keeps what it has finished
                    _save_json(msgspec.json.encode({"experiments": reports, "partial": True}), out_file)
    except (PermissionError, RampsError) as exc:
        fail(str(exc))
    except KeyboardInterrupt:
        if not reports:
            raise typer.Exit(130)
        err.print(f"interrupted: the {len(reports)} finished experiment(s) follow")
        _emit(reports, print_fault_report, as_json=as_json, out_file=out_file)
        raise typer.Exit(130)
    _emit(reports, print_fault_report, as_json=as_json, out_file=out_file)
    if any(r.summary["lost"] or r.summary["duplicated"] for r in reports):
        raise typer.Exit(1)


@testbed_app.command("fidelity")
def testbed_fidelity(
    caps: bool = typer.Option(True, "--caps/--no-caps", help="per-program CPU caps (the default; --no-caps to see why)"),
    cores: int = typer.Option(4, "--cores", min=1, max=64, help="emulated cores of the robot"),
    quota: float = typer.Option(0.8, "--quota", min=0.05, help="host cores of the robot"),
    work: float = typer.Option(2.0, "--work", min=0.1, help="work units per program"),
    as_json: bool = typer.Option(False, "--json", help="write the report as JSON to stdout"),
    out_file: Optional[Path] = typer.Option(None, "--out", help="also save the JSON here"),
) -> None:
    """How closely a testbed robot follows processor sharing: k programs next to b busy
    processes, completion times and the robot's CPU against the model (about 3 minutes)."""
    from ramps.errors import RampsError
    from ramps.testbed.fidelity import run_fidelity

    def show(rep, console) -> None:
        from rich.table import Table

        t = Table(title=f"testbed robot of {rep.cores} cores on {rep.quota:g} host cores, "
                        f"per-program caps {'on' if rep.caps else 'off'}, {rep.work:g} units each")
        for col in ("programs", "busy", "model s", "measured s", "range s", "error", "robot CPU", "model CPU",
                    "unit CPU s", "corrected error"):
            t.add_column(col, justify="right")
        for c in rep.cases:
            t.add_row(str(c.programs), str(c.busy), f"{c.model:.1f}", f"{c.mean:.1f}", f"{c.first:.1f}-{c.last:.1f}",
                      f"{c.error:+.0%}", f"{c.cpu:.2f}", f"{c.cpu_model:.2f}", f"{c.unit_cpu:.2f}",
                      f"{c.corrected_error:+.0%}")
        console.print(t)
        console.print(f"mean |error|: completion {rep.mean_abs_error:.0%}, robot CPU {rep.mean_abs_cpu_error:.0%}, "
                      f"completion corrected for the host's speed {rep.mean_abs_corrected_error:.0%}; a work unit "
                      f"cost {rep.unit_cpu_s[0]:.2f} then {rep.unit_cpu_s[1]:.2f} CPU s in this process",
                      highlight=False)

    err.print(f"fidelity of one testbed robot, caps {'on' if caps else 'off'} ...")
    try:
        rep = run_fidelity(caps=caps, cores=cores, quota=quota, work=work,
                           log=lambda m: err.print(m, highlight=False))
    except (PermissionError, RampsError, RuntimeError) as exc:
        fail(str(exc))
    _emit([rep], show, as_json=as_json, out_file=out_file)


@testbed_app.command("campaign")
def testbed_campaign(
    runs: int = typer.Option(20, "--runs", min=1, help="number of runs (each starts its own testbed)"),
    seed: int = typer.Option(0, "--seed", help="seed of the first run; run i uses seed*1000000+i"),
    robots: int = typer.Option(4, "--robots", min=2, max=8, help="robots per run (r1 is the origin)"),
    duration: float = typer.Option(20.0, "--duration", min=5.0, help="seconds of workload and faults per run"),
    policy: str = typer.Option("ramps", "--policy", "-p", help=POLICY_HELP),
    lease_ms: Optional[int] = typer.Option(None, "--lease-ms", help="Zenoh lease of every node, ms"),
    discovery: str = typer.Option("both", "--discovery", help=DISCOVERY_HELP),
    keep_logs: Optional[Path] = typer.Option(None, "--keep-logs", help="keep the node logs and traces of failed runs here"),
    only_seed: Optional[int] = typer.Option(None, "--only-seed", help="re-run just this run seed (as printed by a failed run)"),
    stress: bool = typer.Option(True, "--stress/--no-stress", help="also stall nodes alone (0.5-5 s, the origin too), kill nodes alone, and put CPU pressure on robots; then check nothing was restarted without cause or left running (--no-stress: crashes, cuts and freezes only, as before 2026-11-23)"),
    as_json: bool = typer.Option(False, "--json", help="write the report as JSON to stdout"),
    out_file: Optional[Path] = typer.Option(None, "--out", help="also save the JSON here"),
) -> None:
    """Random crashes, cuts, freezes and recoveries of non-origin robots during a workload, on real
    processes; after every run: every program completed exactly once, recovered robots rejoined.
    With --stress (default) also node-only stalls and crashes and CPU pressure, and the checks that no
    program was restarted without cause and nothing was left running."""
    from ramps.errors import RampsError
    from ramps.experiments.report import print_campaign
    from ramps.testbed.experiments import run_campaign

    _check_policy(policy)
    _check_discovery(discovery)

    def progress(done, total, run):
        mark = "ok" if run.ok else (f"FAILED lost {run.lost} dup {run.duplicated} not rejoined {run.not_rejoined}"
                                    + (f" unexplained restarts {run.unexplained}" if run.unexplained else "")
                                    + (f" left running {run.left_running}" if run.left_running else "")
                                    + (f" orphans {run.orphans}" if run.orphans else ""))
        err.print(f"run {done}/{total} (seed {run.seed}): {run.programs} programs, "
                  f"{sum(1 for f in run.faults if f[2] != 'recover')} faults, {run.seconds:.0f} s: {mark}",
                  highlight=False)

    try:
        rep = run_campaign(runs, seed, policy=policy, robots=robots, duration=duration, lease_ms=lease_ms,
                           discovery=discovery, keep_logs=keep_logs, only_seed=only_seed, progress=progress,
                           stress=stress)
    except (PermissionError, RampsError) as exc:
        fail(str(exc))
    if rep.interrupted:
        err.print(f"interrupted: the {rep.runs} run(s) that finished follow")
    _emit([rep], print_campaign, as_json=as_json, out_file=out_file)
    if stress:
        err.print(f"stress checks: {rep.unexplained_restarts} unexplained restart(s), {rep.left_running} robot(s) "
                  f"left running programs, {rep.orphans} orphaned process(es) of nodes killed alone", highlight=False)
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


def main() -> None:
    app()


if __name__ == "__main__":
    main()
