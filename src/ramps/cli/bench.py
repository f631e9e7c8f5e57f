"""``ramps bench``: benchmarks that print figures and save them as JSON.

    ramps bench sim          # the paper sweep and a 1000-robot scenario, timed
    ramps bench dispatch     # submit-to-result latency and throughput on a loopback team
    ramps bench first-calls  # a fresh team's first calls of a heavy program, at once and one by one
    ramps bench fuzz         # hostile input at the decoders and the core
    ramps bench flood        # a real node under a flood of malformed messages
    ramps bench metrics      # what --metrics costs an idle node

This module parses and prints (rules in ``ramps.cli.common``).
"""

from __future__ import annotations

import json
import statistics
from pathlib import Path
from typing import Any, Optional

import typer

from ramps.cli.common import command_group, emit, err, fail, out

bench_app = command_group("Benchmarks that print figures and save them as JSON.")


@bench_app.command("metrics")
def bench_metrics(
    seconds: float = typer.Option(60.0, "--seconds", min=5.0, help="how long both nodes are measured"),
    scrape_every: float = typer.Option(15.0, "--scrape-every", min=0.1,
                                       help="seconds between scrapes (Prometheus' default is 15)"),
    out_file: Path = typer.Option(Path("bench-results/metrics.json"), "--out", "-o", help="where to save the JSON"),
) -> None:
    """CPU cost of serving Prometheus metrics on an idle node: one node with --metrics (scraped over
    HTTP) next to one without, for the same seconds, plus the CPU of one /metrics render."""
    from ramps.bench.metrics_cost import measure_idle_cost

    err.print(f"two idle one-robot teams on loopback, one serving metrics scraped every {scrape_every:g} s; "
              f"measuring {seconds:g} s ...")
    r = measure_idle_cost(seconds=seconds, scrape_every=scrape_every)
    out.print(f"idle node with metrics: {r['node_with_metrics_core_pct']:.2f}% of a core, without: "
              f"{r['node_without_metrics_core_pct']:.2f}%; serving metrics costs "
              f"{r['metrics_cost_core_pct']:+.2f}% of a core ({r['scrapes']} scrapes in {r['seconds']:.0f} s)")
    out.print(f"one /metrics render ({r['render_bytes']} bytes, a busy node's series): {r['render_cpu_ms']:.2f} ms "
              f"CPU = {r['render_cost_at_15s_core_pct']:.3f}% of a core scraped every 15 s, "
              f"{r['render_cost_at_1s_core_pct']:.2f}% every 1 s")
    out_file.parent.mkdir(parents=True, exist_ok=True)
    out_file.write_text(json.dumps(r, indent=2) + "\n")
    out.print(f"saved {out_file}")


@bench_app.command("sim")
def bench_sim(
    runs: int = typer.Option(3, "--runs", "-n", min=1, help="runs per configuration in the sweep"),
    robots: int = typer.Option(1000, "--robots", min=1, help="robots in the large scenario"),
    programs: int = typer.Option(10_000, "--programs", min=1, help="programs in the large scenario"),
    origins: int = typer.Option(10, "--origins", min=1, help="robots that submit programs in the large scenario"),
    settings: list[str] = typer.Option([], "--set", help="change a core setting of the large team, e.g. "
                                       "--set heartbeat_period=5 --set heartbeat_timeout=15 --set report_fanout=16"),
    report_period: Optional[float] = typer.Option(None, "--report-period", min=0.1,
                                                  help="seconds between a robot's periodic load reports in the "
                                                       "large team (default: the simulator's, 2)"),
    large_only: bool = typer.Option(False, "--large-only", help="time the large team only, not the paper sweep"),
    out_file: Path = typer.Option(Path("bench-results/sim.json"), "--out", "-o", help="where to save the JSON"),
) -> None:
    """Time the full paper sweep and a large-team scenario."""
    from ramps.bench.simulator import bench_large, bench_sweep, machine
    from ramps.cli.sim import _config_with

    if origins > robots:
        fail("--origins cannot exceed --robots")
    config = _config_with(settings) if settings else None
    sweep = None
    if not large_only:
        err.print(f"sweep: unloaded + loaded, {runs} run(s) each, 3 simulations per run ...")
        sweep = bench_sweep(runs)
        out.print(f"paper sweep (unloaded + loaded, {runs} runs each): {sweep['wall_seconds']:.2f} s "
                  f"({sweep['unloaded']['simulations'] + sweep['loaded']['simulations']} simulations)")
    err.print(f"large team: {robots} robots, {programs} programs from {origins} origins ...")
    large = bench_large(robots, programs, origins, config=config, report_period=report_period)
    out.print(f"large team ({robots} robots, {programs} programs): {large['wall_seconds']:.2f} s wall, "
              f"{large['cpu_seconds']:.2f} s CPU, {large['events']} events ({large['events_per_s']:.0f}/s), "
              f"completed {large['completed']}, lost {large['lost']}, duplicated {large['duplicated']}, "
              f"virtual makespan {large['makespan_virtual_s']:.1f} s, {large['makespan_over_bound']:.3f}x "
              f"the largest bound (capacity {large['capacity_bound']:.1f} s, release {large['release_bound']:.1f} s, "
              f"fluid {large['fluid_bound']:.1f} s)")
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
    baseline: str = typer.Option("fe693da", "--baseline", metavar="NAME|FILE",
                                 help="saved figures to set these beside: fe693da (the code of 2026-11-21, at full "
                                      "speed), 0.1.0, or a JSON file this command saved; none: no comparison"),
    against: Path | None = typer.Option(None, "--against", metavar="DIR",
                                        help="also measure the ramps in this checkout (e.g. `git worktree add DIR "
                                             "fe693da`), in turns with this one"),
    rounds: int = typer.Option(1, "--rounds", "-n", min=1, help="measurements of each code, in turns"),
    out_file: Path = typer.Option(Path("bench-results/dispatch.json"), "--out", "-o", help="where to save the JSON"),
) -> None:
    """Latency from submit to result of a no-op program on a real loopback team, and throughput, beside
    earlier code's.

    Wall-clock figures follow the machine's load: only codes measured in turns on the same machine at the
    same time compare (--against); CPU per program follows the code and compares with a saved baseline too.
    The JSON holds the last run's figures at its top, every run, and the comparisons."""
    from ramps.bench import dispatch as d

    base = None if baseline == "none" else d.load_baseline(baseline)
    kw: dict[str, Any] = dict(nodes=nodes, calls=calls, burst=burst, window=window)
    ours: list[dict] = []
    theirs: list[dict] = []
    for r in range(rounds):
        order = ["this", "against"] if r % 2 == 0 else ["against", "this"]
        for which in order:
            if which == "against" and against is None:
                continue
            err.print(f"{'this code' if which == 'this' else against}: {nodes} nodes on loopback; {calls} sequential "
                      f"calls, then {burst} with {window} in flight ...")
            res = d.bench_dispatch(**kw) if against is None or which == "this" else d.measure_code(against, **kw)
            (ours if which == "this" else theirs).append(res)
            _show_dispatch("this" if which == "this" else str(against), res)
    result = dict(ours[-1], runs=ours)
    if theirs:
        result["against"] = {"checkout": str(against), "runs": theirs,
                             "vs": d.compare(_median_run(d, ours), {"runs": theirs})}
        _show_comparison(f"against {against}, measured in turns", result["against"]["vs"])
    if base is not None:
        result["vs_baseline"] = {"baseline": baseline, "vs": d.compare(_median_run(d, ours), base)}
        _show_comparison(f"against the saved baseline {baseline} ({base.get('note', '')})", result["vs_baseline"]["vs"])
    out_file.parent.mkdir(parents=True, exist_ok=True)
    out_file.write_text(json.dumps(result, indent=2) + "\n")
    out.print(f"saved {out_file}")


def _median_run(d: Any, runs: list[dict]) -> dict:
    """A run whose figures are the medians of ``runs`` (what ``compare`` reads)."""
    med = d.baseline_figures({"runs": runs})
    return {"p50_ms": med["p50_ms"], "remote_p50_ms": med["remote_p50_ms"],
            "throughput_per_s": med["throughput_per_s"], "burst_cpu_us": {"all": med["cpu_us"]}}


def _show_dispatch(label: str, res: dict) -> None:
    cpu = res["burst_cpu_us"]
    out.print(f"{label}: p50 {res['p50_ms']:.2f} ms at the origin (p99 {res['p99_ms']:.2f}), offloaded p50 "
              f"{res['remote_p50_ms']:.2f} ms (p99 {res['remote_p99_ms']:.2f}, {res['remote_calls']} calls); "
              f"{res['throughput_per_s']:.0f} programs/s ({res['completed']}/{res['burst']} completed; ran on "
              f"{res['burst_hosts']}); CPU per program {sum(cpu.values()):.0f} us ("
              + ", ".join(f"{k} {v:.0f}" for k, v in cpu.items()) + f"); load {res['loadavg'][0]:.1f}",
              highlight=False)


def _show_comparison(title: str, vs: dict) -> None:
    out.print(title + ":", highlight=False)
    names = {"p50_ms": "p50 at the origin, ms", "remote_p50_ms": "p50 offloaded, ms",
             "throughput_per_s": "programs/s", "cpu_us": "CPU per program, us"}
    for key, row in vs.items():
        out.print(f"  {names[key]:24} {row['this']:9.2f} against {row['baseline']:9.2f}: x{row['ratio']:.2f} "
                  f"({'better or as good' if row['better'] else 'worse'})", highlight=False)


@bench_app.command("first-calls")
def bench_first_calls_cmd(
    nodes: int = typer.Option(3, "--nodes", min=1, help="real node processes (robots with --testbed)"),
    cores: int = typer.Option(2, "--cores", min=1, help="cores each node declares (its idle workers); "
                              "with --testbed, the emulated cores each robot has"),
    calls: int = typer.Option(6, "--calls", min=1, help="calls in each phase"),
    rounds: int = typer.Option(1, "--rounds", "-n", min=1, help="times on a fresh team"),
    testbed: bool = typer.Option(False, "--testbed", help="on a fresh emulated team a round (`ramps testbed`: "
                                 "a network namespace and a cpu cgroup a robot; needs root), not on loopback"),
    quota: Optional[float] = typer.Option(None, "--quota", min=0.01, help="with --testbed: host cores each robot "
                                          "gets (default: nine tenths of this host's cores shared out)"),
    keep_logs: Optional[Path] = typer.Option(None, "--keep-logs", help="with --testbed: copy each round's node "
                                             "logs and traces to DIR/round-<i>"),
    period_ms: float = typer.Option(10.0, "--period-ms", min=1.0, max=1000.0, help="with --testbed: the robots' "
                                    "CFS period: the kernel holds a quota over each, so a call shorter than one "
                                    "period's quota runs at the host's speed (100: the kernel's default)"),
    out_file: Path = typer.Option(Path("bench-results/first-calls.json"), "--out", "-o",
                                  help="where to save the JSON"),
) -> None:
    """A fresh team's first calls of a heavy program (route_plan: OR-Tools), all at once, against the same
    calls one after another and at once again; and the memory of each node's fork server and workers.
    On loopback the nodes share this host's cores; with --testbed each robot has its own (emulated)."""
    if testbed:
        res = _first_calls_on_testbed(nodes, cores, calls, rounds, quota, keep_logs, int(period_ms * 1000))
    else:
        from ramps.bench.firstcalls import bench_first_calls

        err.print(f"{rounds} round(s): a fresh team of {nodes} nodes on loopback, {calls} route_plan calls at once "
                  f"(cold), one after another, at once (warm) ...")
        res = bench_first_calls(nodes=nodes, cores=cores, calls=calls, rounds=rounds)
    for i, r in enumerate(res["rounds"], 1):
        c, s, w = r["cold_at_once"], r["warm_one_after_another"], r["warm_at_once"]
        out.print(f"round {i} (team up in {r['team_start_s']:.1f} s): cold at once p50 {c['p50_ms']:.0f} ms "
                  f"[{c['min_ms']:.0f}-{c['max_ms']:.0f}], one after another p50 {s['p50_ms']:.0f} ms "
                  f"[{s['min_ms']:.0f}-{s['max_ms']:.0f}], warm at once p50 {w['p50_ms']:.0f} ms "
                  f"[{w['min_ms']:.0f}-{w['max_ms']:.0f}]; cold at once / one after another: "
                  f"{r['cold_over_sequential_p50']:.1f}x, / warm at once: {r['cold_over_warm_at_once_p50']:.1f}x",
                  highlight=False)
        for when in ("memory_start", "memory_after"):
            parts = []
            for robot, m in r[when].items():
                fs, ws = m["fork_server"] or {}, m["workers"]
                wk = (f"{len(ws)} workers PSS {statistics.fmean(x['pss_mb'] for x in ws):.1f} / "
                      f"USS {statistics.fmean(x['uss_mb'] for x in ws):.1f} / "
                      f"RSS {statistics.fmean(x['rss_mb'] for x in ws):.1f} MB each" if ws else "no workers")
                parts.append(f"{robot}: fork server PSS {fs.get('pss_mb', 0):.1f} / RSS {fs.get('rss_mb', 0):.1f} "
                             f"MB ({fs.get('cpu_s', 0):.2f} CPU-s), {wk}; executor PSS {m['executor_pss_mb']:.1f} MB")
            out.print(f"  {when.replace('_', ' ')}: " + "; ".join(parts), highlight=False)
    for key, what in (("cold_over_sequential_p50", "one after another"), ("cold_over_warm_at_once_p50", "warm at once")):
        agg = res[key]
        out.print(f"cold at once / {what} (p50): median {agg['median']:.1f}x "
                  f"[{agg['min']:.1f}-{agg['max']:.1f}] over {rounds} round(s)", highlight=False)
    out_file.parent.mkdir(parents=True, exist_ok=True)
    out_file.write_text(json.dumps(res, indent=2) + "\n")
    out.print(f"saved {out_file}")


def _first_calls_on_testbed(robots: int, cores: int, calls: int, rounds: int, quota: float | None,
                            keep_logs: Path | None, period_us: int) -> dict:
    from ramps.bench.firstcalls_testbed import bench_first_calls_testbed, default_quota
    from ramps.errors import RampsError
    from ramps.testbed import Testbed

    q = quota if quota is not None else default_quota(robots)
    err.print(f"{rounds} round(s): a fresh emulated team of {robots} robots of {cores} cores on {q:g} host cores "
              f"each ({q / cores:.2f} a core, a CFS period of {period_us / 1000:g} ms), {calls} route_plan calls "
              f"at once (cold), one after another, at once (warm) ...")
    try:
        res = bench_first_calls_testbed(lambda: Testbed(robots, cores=cores, quota=q, speed=1.0, period_us=period_us,
                                                        config={"preload_bundled": True}),
                                        robots=robots, cores=cores, quota=q, calls=calls, rounds=rounds,
                                        keep_logs=keep_logs)
        return res | {"period_ms": period_us / 1000}
    except (PermissionError, RampsError) as exc:
        fail(str(exc))


@bench_app.command("accelerators")
def bench_accelerators_cmd(
    detects: int = typer.Option(12, "--detects", min=1, help="GPU-capable calls (matrix products with PyTorch)"),
    plans: int = typer.Option(12, "--plans", min=0, help="CPU-only calls (burn) submitted with them"),
    size: int = typer.Option(2048, "--size", min=16, help="matrix size of a detect call"),
    reps: int = typer.Option(10, "--reps", min=1, help="matrix products per detect call"),
    cores: int = typer.Option(4, "--cores", min=1, help="cores each of the three nodes offers"),
    out_file: Path = typer.Option(Path("bench-results/accelerators.json"), "--out", "-o",
                                  help="where to save the JSON"),
) -> None:
    """A team of three real nodes, one offering the machine's NVIDIA GPU, runs GPU-capable and CPU-only
    programs at once; then the same with the GPU switched off. Needs torch and nvidia-ml-py (and a GPU)."""
    from ramps.bench.accelerators import bench_accelerators

    err.print(f"two fresh teams of 3 nodes ({cores} cores each): {detects} detect + {plans} burn calls at once, "
              f"with g's GPU offered, then without ...")
    res = bench_accelerators(detects=detects, plans=plans, size=size, reps=reps, cores=cores)
    for label, run in res["runs"].items():
        out.print(f"{label}: makespan {run['makespan_s']:.2f} s (warm-up {run['warm_up_makespan_s']:.2f} s); "
                  f"offered {run['offered'] or 'no accelerator'}; detect device time median: GPU "
                  f"{run['detect_gpu_s_median']} s, CPU {run['detect_cpu_s_median']} s", highlight=False)
        for where, n in run["where"].items():
            out.print(f"  {n:3d} x {where}", highlight=False)
        if run["gpu_seen"]:
            peak = max(run["gpu_seen"], key=lambda s: s.get("programs", 0))
            out.print(f"  g's reports while busy: {peak}", highlight=False)
    out.print(f"cpu only / gpu offered: {res['speedup']}x"
              f"{'' if res['cgroups'] else ' (no cpu cgroups: every node measured the whole machine)'}",
              highlight=False)
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
    from ramps.bench.fuzz import run_fuzz

    err.print(f"fuzzing with {inputs} inputs, seed {seed} ...")
    res = run_fuzz(inputs=inputs, seed=seed, progress=lambda n: err.print(f"  {n} inputs", highlight=False))

    def show(r, console) -> None:
        console.print(f"fuzz: {r['inputs']} inputs in {r['seconds']:.2f} s ({r['inputs_per_s']:.0f}/s), "
                      f"seed {r['seed']}: {r['decoder_inputs']} at the wire decoder ({r['decoded']} decoded, "
                      f"{r['wire_errors']} refused), {r['args_inputs']} at the argument decoder, "
                      f"{r['core_events']} core events (+{r['core_from_decoder']} decoded messages) on "
                      f"{r['core_nodes']} nodes, {r['programs_delivered']} programs delivered ({r['deadline_misses']} missed "
                      f"their deadline, {r['submits_refused']} submissions refused); "
                      f"unhandled exceptions: {r['exceptions']}", highlight=False)
        for x in r["exception_samples"]:
            console.print(f"  {x['target']} ({x['kind']}): {x['error']}", highlight=False)

    emit([res], show, as_json=as_json, out_file=out_file)
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
    from ramps.bench.flood import bench_flood

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
                      f"{r['rss_after_mb']['r1']:.1f} MB after (growth {r['rss_growth_mb']['r1']:+.1f} MB; private "
                      f"{r['private_growth_mb']['r1']:+.1f} MB); "
                      f"alive: {r['alive']}", highlight=False)
        for f in r["failures"]:
            console.print(f"  {f}", highlight=False)

    emit([res], show, as_json=as_json, out_file=out_file)
    if res["programs_ok"] != res["programs"] or not all(res["alive"].values()):
        raise typer.Exit(1)



@bench_app.command("team-size")
def bench_team_size_cmd(
    nodes: list[int] = typer.Option([10, 25], "--nodes", "-n", min=4, max=200,
                                    help="team sizes to measure, one after another (repeatable)"),
    idle: float = typer.Option(20.0, "--idle", min=2.0, metavar="SECONDS", help="seconds over which an idle node's cost is measured"),
    settle: float = typer.Option(40.0, "--settle", min=0.0, metavar="SECONDS",
                                 help="measure idle nodes from this many seconds after they started (a node "
                                 "re-measures its speed every 3 s for its first 36 s)"),
    units: float = typer.Option(0.05, "--units", min=0.001, max=5.0, help="work units of each burst program"),
    form_timeout: float = typer.Option(120.0, "--form-timeout", min=5.0, metavar="SECONDS",
                                       help="seconds the team may take to form (every node seeing all others)"),
    origins: int = typer.Option(3, "--origins", min=1, max=20, help="robots that submit the bursts (r1, r2, ...)"),
    router: bool = typer.Option(False, "--router", help="the nodes as Zenoh clients of one router (a star, as a large "
                                "team runs) instead of peers linked pairwise"),
    cpu_quota: float = typer.Option(None, "--cpu-quota", min=0.011, max=64.0, metavar="CORES",
                                    help="run every node in a cpu cgroup of this many host cores (a robot of one "
                                    "emulated core; needs root), its programs sized by --program-seconds, and "
                                    "compare the burst with the simulator's run of the same team (e.g. 0.018 for "
                                    "100 robots on 2 host cores)"),
    program_seconds: float = typer.Option(20.0, "--program-seconds", min=0.5, max=600.0, metavar="SECONDS",
                                          help="with --cpu-quota: each burst program's seconds alone on a robot"),
    burst_timeout: float = typer.Option(120.0, "--burst-timeout", min=5.0, metavar="SECONDS",
                                        help="seconds a burst may take"),
    lead: float = typer.Option(0.0, "--lead", min=0.0, max=60.0, metavar="SECONDS",
                               help="seconds between the applications connecting to the origins and the first "
                               "burst (0: at once, as an application that connects and submits)"),
    keep_logs: Path = typer.Option(None, "--keep-logs", metavar="DIR",
                                   help="keep every node's log and trace under DIR/size-N/"),
    as_json: bool = typer.Option(False, "--json", help="print the figures as JSON"),
    out_file: Path = typer.Option(Path("bench-results/team-size.json"), "--out", "-o", help="where to save the JSON"),
) -> None:
    """What each robot of a team of N real nodes on loopback costs: time to form, idle CPU, memory, threads and
    traffic per node, a burst of 2N programs from --origins robots, a fifth of the robots killed at once.

    With root the team runs in a network namespace of its own, so the traffic counted is the team's alone.
    Without --cpu-quota the nodes share this machine's cores: where programs run says little; that programs
    come back once, and how soon survivors hear each other, does. With --cpu-quota every robot is a cgroup of
    one emulated core and the burst is compared with the simulator's makespan for the same team. Minutes per
    size (a 50-node team starts 50 Python processes)."""
    from ramps.bench.teamsize import run_isolated

    err.print(f"team sizes {', '.join(map(str, nodes))}: each formed, idle {idle:g} s, a burst, a fifth killed ...")
    res = run_isolated(list(nodes), idle=idle, units=units, form_timeout=form_timeout, router=router,
                       origins=origins, cpu_quota=cpu_quota, program_seconds=program_seconds, settle=settle,
                       lead=lead,
                       burst_timeout=burst_timeout, keep_logs=None if keep_logs is None else str(keep_logs.resolve()))

    def show(r, console) -> None:
        console.print(f"{'nodes':>5} {'formed s':>8} {'CPU %/node':>10} {'all %':>6} {'PSS MiB':>7} {'threads':>7} "
                      f"{'lo B/s/node':>11} {'burst':>12} {'runs':>5} {'killed':>6} {'heard s':>7} {'lost':>4}",
                      highlight=False)
        for run in r["runs"]:
            i, b, k = run.get("idle", {}), run.get("burst", {}), run.get("kill", {})
            burst = f"{b.get('delivered', '-')}/{b.get('programs', '-')} {b.get('makespan_s') or '-'}s" if b else "-"
            once = "-" if not b else str(b.get("runs_counted"))
            console.print(f"{run['nodes']:>5} {run['formed_s'] if run['formed_s'] is not None else 'no':>8} "
                          f"{i.get('with_workers_cpu_pct', {}).get('median', '-'):>10} "
                          f"{i.get('all_nodes_cpu_pct', '-'):>6} {i.get('pss_mib', {}).get('median', '-'):>7} "
                          f"{i.get('threads', {}).get('median', '-'):>7} {i.get('lo_bytes_per_node_s', '-'):>11} "
                          f"{burst:>12} {once:>5} {k.get('killed', '-'):>6} "
                          f"{k.get('heard_s_after_kill') if k.get('heard_s_after_kill') is not None else '-':>7} "
                          f"{(k.get('programs', 0) - k.get('delivered', 0)) if k else '-':>4}", highlight=False)
        console.print(f"({'own network namespace' if r['isolated'] else 'the host loopback: traffic of others counted too'}; "
                      "CPU: node, fork server and workers, % of one core; PSS: proportional memory; runs: runs the robots "
                      "ended in the burst, more than its programs where programs were moved)", highlight=False)
        for run in r["runs"]:
            sim = run.get("burst", {}).get("simulator")
            if sim and "ratio_ideal" in sim:
                console.print(f"({run['nodes']} robots of {run['cpu_quota']:g} host cores: burst "
                              f"{run['burst']['makespan_s']} s, {run['burst']['robots_by_programs']} robots by "
                              f"programs; the simulator {sim['ideal']['makespan_s']} s "
                              f"{sim['ideal']['robots_by_programs']} (ratio {sim['ratio_ideal']}), with the "
                              f"node's CPU {sim['with_node']['makespan_s']} s ({sim['ratio_with_node']}), at the "
                              f"programs' own speed {sim['corrected']['makespan_s']} s ({sim['ratio_corrected']}))",
                              highlight=False)
            if run.get("router") and run.get("idle"):
                console.print(f"({run['nodes']} nodes: Zenoh clients of one router, which used "
                              f"{run['idle']['router_cpu_pct']}% of a core idle; loopback counts each message twice)",
                              highlight=False)

    emit([res], show, as_json=as_json, out_file=out_file)
