"""Printing experiment results for people (rich tables) and scripts (JSON).

Rules: rendering only. Every figure printed here is a field of the report
object that ``--json`` writes, so what a person reads and what a script
counts are the same data.
"""

from __future__ import annotations

from rich.console import Console
from rich.table import Table

from ramps.experiments.paper import ExperimentReport
from ramps.sim.engine import SimResult

_CLASS_STYLE = {"optimal": "green", "near_optimal": "yellow", "non_optimal": "red"}
_CLASS_SHORT = {"optimal": "optimal", "near_optimal": "near", "non_optimal": "NON"}


def _median_run(cfg):
    runs = sorted(cfg.runs, key=lambda r: r.makespan)
    return runs[len(runs) // 2]


def _cls(run) -> str:
    return f"[{_CLASS_STYLE[run.classification]}]{_CLASS_SHORT[run.classification]}[/]"


def print_experiment(report: ExperimentReport, console: Console) -> None:
    title = (f"{report.experiment} team, policy {report.policy}: {report.runs} run(s) per configuration, "
             f"seed {report.seed} (median run shown; classes of all runs listed)")
    table = Table(title=title, title_justify="left", show_lines=False, pad_edge=False)
    loaded = report.experiment == "loaded"

    def col(name: str, right: bool = True) -> None:
        table.add_column(name, justify="right" if right else "left", no_wrap=True)

    col("progs")
    col("R1..R5" if loaded else "robots", right=False)
    col("distribution R1..Rn", right=False)
    col("class (each run)", right=False)
    col("time s")
    if loaded:
        col("optimum s")
        col("/opt")
    col("RR s")
    col("/RR")
    col("1 robot s")
    col("speedup")
    if not loaded:
        col("paper RAMP/RR/1", right=False)
    prev = None
    for cfg in report.configs:
        run = _median_run(cfg)
        if prev is not None and prev != cfg.programs:
            table.add_section()
        prev = cfg.programs
        dist = "-".join(str(x) for x in run.distribution)
        if loaded:
            dist = f"{dist} (mean {'-'.join(f'{x:g}' for x in cfg.mean_distribution)})"
        row = [str(cfg.programs), cfg.pattern if loaded else str(cfg.team_size), dist,
               " ".join(_cls(r) for r in cfg.runs), f"{cfg.median_makespan:.1f}"]
        if loaded:
            row += [f"{run.optimum_makespan:.1f}", f"{cfg.median_makespan / run.optimum_makespan:.3f}"]
        row += [f"{cfg.median_round_robin:.1f}", f"{cfg.median_makespan / cfg.median_round_robin:.3f}",
                f"{cfg.median_single:.1f}", f"{cfg.median_single / cfg.median_makespan:.2f}x"]
        if not loaded:
            p = cfg.paper
            row.append(f"{p['ramps']:.0f}/{p['round_robin']:.0f}/{p['single']:.0f}" if p else "")
        table.add_row(*row)
    console.print(table)
    s = report.summary
    line = (f"[bold]{report.experiment} / {report.policy}[/]: {s.distributions} distributions: "
            f"{s.optimal} optimal ({s.optimal_share:.0%}), {s.near_optimal} near optimal, "
            f"{s.non_optimal} non optimal -> [bold]{s.optimal_or_near_share:.0%} optimal or near optimal[/]; "
            f"worst median makespan vs round robin {s.worst_ratio_to_round_robin:.3f}")
    if loaded:
        line += (f"; worst run vs model optimum {s.worst_ratio_to_optimum:.3f}; "
                 f"programs on a loaded robot while an unloaded one had a free core: {s.free_core_violations} run(s)")
    line += f"; lost {s.lost}, duplicated {s.duplicated}; {report.wall_seconds:.1f} s"
    console.print(line)
    if report.experiment == "unloaded":
        console.print("[dim]paper (Valkov et al. 2021, section 4.1): 89% optimal or near optimal (46% optimal), "
                      "up to 23% slower than round robin. Its single-robot times are slower than processor "
                      "sharing predicts (1 GB Pi 3 under 5-30 solver processes); the simulator models CPU only.[/]")


def print_sim_result(res: SimResult, console: Console) -> None:
    table = Table(title=f"scenario {res.scenario}: policy {res.policy}, seed {res.seed}", title_justify="left")
    table.add_column("robot")
    table.add_column("programs run", justify="right")
    table.add_column("placements", justify="right")
    table.add_column("host failures", justify="right")
    table.add_column("blacklisted (at end)")
    stats = {s.robot: s for s in res.statistics}
    for name in res.robots:
        st = stats.get(name)
        table.add_row(name, str(res.distribution.get(name, 0)), str(st.placements if st else "-"),
                      str(st.host_failures if st else "-"), ", ".join(st.blacklisted) if st else "(down)")
    console.print(table)
    console.print(
        f"makespan {res.makespan:.2f} s; completed {res.completed}, failed {res.failed}, "
        f"lost {res.lost}, duplicated {res.duplicated}; {res.events} events, "
        f"{res.messages_sent} messages ({res.messages_dropped} dropped); "
        f"simulated {res.end_time:.1f} s in {res.wall_seconds:.2f} s"
    )


def print_fault_report(rep, console: Console) -> None:
    """Tables 5-10 style: distributions after each failure, and recovery figures."""
    from collections import defaultdict

    from ramps.experiments.faults import ROBOTS

    marks = {"crash": "RC", "network": "NF"}
    if rep.mode == "sequential":
        table = Table(title=f"{rep.world}: {rep.mode} {rep.kind} failures (R5, R4, R3, R2, {rep.gap:g} s apart), "
                            f"policy {rep.policy}",
                      title_justify="left")
        table.add_column("run")
        table.add_column("dist")
        for r in ROBOTS:
            table.add_column(r, justify="right")
        table.add_column("class")
        for i, run in enumerate(rep.runs, 1):
            failed: dict[str, str] = {}
            for label, dist in run.distributions.items():
                row = [f"run {i}" if label == "D1" else "", label]
                for r in ROBOTS:
                    row.append(str(dist[r]) if r in dist else marks.get(failed.get(r, ""), "-"))
                row.append(_CLASS_SHORT[run.classifications[label]])
                table.add_row(*row)
                idx = int(label[1:])
                if idx <= len(run.failures):
                    f = run.failures[idx - 1]
                    failed[f.robot] = f.kind
            table.add_section()
        console.print(table)
    else:
        table = Table(title=f"{rep.world}: {rep.mode} {rep.kind} failures, mean distribution over "
                            f"{len(rep.runs) // 4} run(s), "
                            f"policy {rep.policy}", title_justify="left")
        table.add_column("robots failed")
        for r in ROBOTS:
            table.add_column(r, justify="right")
        table.add_column("classes")
        groups = defaultdict(list)
        for run in rep.runs:
            groups[run.plan].append(run)
        first = next(iter(groups.values()))
        table.add_row("none", *[f"{sum(r.distributions['before'][x] for r in first) / len(first):.2f}" for x in ROBOTS],
                      "")
        for plan, runs in groups.items():
            kinds = {f.robot: f.kind for f in runs[0].failures}
            row = [",".join(sorted(kinds))]
            for x in ROBOTS:
                if x in kinds:
                    row.append(marks[kinds[x]])
                else:
                    row.append(f"{sum(r.distributions['after'][x] for r in runs) / len(runs):.2f}")
            row.append(" ".join(_CLASS_SHORT[r.classifications["after"]] for r in runs))
            table.add_row(*row)
        console.print(table)
    s = rep.summary
    def fmt(x):
        return "-" if x is None else f"{x:.2f} s"
    per = Table(title="every failure: detection (failure to the origin writing the robot off) and recovery "
                      "(failure to every displaced program running again)", title_justify="left")
    for name in ("run", "robot", "kind", "displaced", "detection", "recovery", "lost", "dup"):
        per.add_column(name, justify="right" if name not in ("run", "kind") else "left")
    for i, run in enumerate(rep.runs, 1):
        for j, f in enumerate(run.failures):
            per.add_row(f"{i} {run.plan}" if j == 0 else "", f.robot, f.kind, str(f.displaced), fmt(f.detection),
                        fmt(f.recovery), str(run.lost) if j == 0 else "", str(run.duplicated) if j == 0 else "")
    console.print(per)
    console.print(
        f"[bold]{rep.mode} {rep.kind} / {rep.policy}[/]: {s['completed']}/{s['programs']} programs completed, "
        f"lost {s['lost']}, duplicated {s['duplicated']}; detection median {fmt(s['detection_median_s'])} "
        f"(max {fmt(s['detection_max_s'])}); displaced programs running again within median "
        f"{fmt(s['recovery_median_s'])} (max {fmt(s['recovery_max_s'])}, at most "
        f"{fmt(s.get('recovery_after_detection_max_s'))} after detection); "
        f"{s['optimal_or_near_after_failures']}/{s['distributions_after_failures']} distributions after failures "
        f"optimal or near optimal"
    )


def print_campaign(rep, console: Console) -> None:
    table = Table(title=f"{getattr(rep, 'world', 'simulator')} fault campaign: {rep.runs} runs, seed {rep.seed}, "
                        f"policy {rep.policy}", title_justify="left")
    for name in ("runs", "programs", "faults injected", "completed", "lost", "duplicated", "not rejoined",
                 "failed runs", "time"):
        table.add_column(name, justify="right")
    table.add_row(str(rep.runs), str(rep.programs), str(rep.faults), str(rep.completed), str(rep.lost),
                  str(rep.duplicated), str(rep.not_rejoined), str(len(rep.failed_runs)), f"{rep.wall_seconds:.1f} s")
    console.print(table)
    if getattr(rep, "load_changes", False) or getattr(rep, "moves", 0):
        console.print(f"relocation: {rep.moves} moves started, {rep.moves_aborted} abandoned (the old copy ran on), "
                      f"{rep.resumed} programs delivered from a resumed checkpoint")
    for r in rep.failed_runs[:10]:
        console.print(f"[red]run seed {r.seed}: lost {r.lost}, duplicated {r.duplicated}, not rejoined "
                      f"{r.not_rejoined}[/] (its scenario is in the --json output)")


def print_relocation(rep, console: Console) -> None:
    """Makespans with and without relocation against the hindsight optimum."""
    console.print(f"{rep.robots} robots of {rep.cores} cores, {rep.programs} programs of {rep.work:g} units from r1; "
                  f"{rep.loaded} starts {rep.busy} busy processes at {rep.load_at:g} s. Hindsight optimum "
                  f"{rep.hindsight_optimum:.1f} s (static split {'-'.join(map(str, rep.optimum_distribution))})")
    table = Table(title="relocation after placement", title_justify="left")
    for name in ("seed", "variant", "makespan", "vs hindsight", "moves", "abandoned", "resumed", "distribution",
                 "lost", "dup"):
        table.add_column(name, justify="left" if name in ("variant", "distribution") else "right")
    for r in rep.runs:
        table.add_row(str(r.seed), r.variant, f"{r.makespan:.1f} s", f"{r.ratio:.3f}", str(r.moves),
                      str(r.moves_aborted), str(r.resumed), "-".join(str(v) for v in r.distribution.values()),
                      str(r.lost), str(r.duplicated))
    console.print(table)
    console.print("median vs hindsight: " + ", ".join(f"{k} {v:.3f}" for k, v in rep.median_ratio.items()))


def print_relocation_campaign(rep, console: Console) -> None:
    r = rep.ratios
    console.print(f"{rep.runs} campaign scenarios with faults and load changes (seed {rep.seed}): makespan with "
                  f"relocation / without: median {rep.median:.3f}, p10 {r[len(r) // 10]:.3f}, "
                  f"p90 {r[min(len(r) - 1, 9 * len(r) // 10)]:.3f}, best {r[0]:.3f}, worst {r[-1]:.3f}; better in "
                  f"{rep.better}, worse in {rep.worse}; {rep.moves} moves; lost {rep.lost}, duplicated {rep.duplicated}")


def print_sweep(rep, console: Console) -> None:
    """One row per family of generated several-origins scenarios: makespan
    against the lower bound (and the omniscient oracle), beside round robin."""
    changed = "".join(f", {k}={v}" for k, v in rep.settings.items())
    table = Table(title=f"several origins at once: policy {rep.policy}{changed}, {rep.seeds_per_scenario} seed(s) "
                        f"per scenario, seed {rep.seed}", title_justify="left")
    for name in ("family", "scenarios", "runs", "median", "p90", "worst", "<=2%", "<=5%", "vs oracle",
                 "optimum known", "vs optimum", "at most", "open gap", ">5%: online can't", "round robin median",
                 "round robin worst", "lost", "dup"):
        table.add_column(name, justify="left" if name == "family" else "right", no_wrap=name == "family")

    def ratio(x: float | None) -> str:
        return "-" if x is None else f"{x:.3f}"

    for r in rep.families:
        table.add_row(r.family, str(r.scenarios), str(r.runs), f"{r.median_ratio:.3f}", f"{r.p90_ratio:.3f}",
                      f"{r.worst_ratio:.3f}", f"{r.within_2pct}/{r.scenarios}", f"{r.within_5pct}/{r.scenarios}",
                      f"{r.median_ratio_oracle:.3f}/{r.worst_ratio_oracle:.3f}", f"{r.proven}/{r.scenarios}",
                      f"{ratio(r.median_ratio_optimum)}/{ratio(r.worst_ratio_optimum)}",
                      f"{ratio(r.median_ratio_best_bound)}/{ratio(r.worst_ratio_best_bound)}",
                      f"{100 * r.worst_gap:.1f}%" if r.searched else "-",
                      f"{r.online_impossible}/{r.above_5pct}" if any(s.online_ratio is not None for s in rep.scenarios)
                      else (f"?/{r.above_5pct}" if r.searched else "-"),
                      f"{r.median_round_robin_ratio:.3f}", f"{r.worst_round_robin_ratio:.3f}", str(r.lost),
                      str(r.duplicated))
    console.print(table)
    console.print("Pairs are median/worst. Ratios are the median makespan over seeds divided by the lower bound (no schedule can do better; "
                  "the exact optimum lies between it and the oracle, a central scheduler that knows every robot's "
                  "exact state). The exact optimum is known where the oracle reaches the bound, or where "
                  "a search proved it within --exact-seconds; \"at most\" (median/worst) divides by the optimum "
                  "where it is known and by the best bound where it is open (an upper limit on the ratio to "
                  "the optimum), and the open gap is the widest of how far the best schedule found lies above "
                  "that bound. \">5%: online can't\" counts the scenarios where the policy is more than 5% above "
                  "the best bound, and of them those where no placement deciding each program at its release "
                  "can be within 5% of the optimum on the scenario and its prefixes (--online-seconds). "
                  + f"{rep.wall_seconds:.1f} s.")
    shown = [s for s in rep.scenarios if s.online_ratio is not None]
    if shown:
        console.print("More than 5% above the best bound: " + "; ".join(
            f"{s.name}: {s.ratio_best_bound:.3f} of the bound, optimum at most {s.best_schedule:.2f} s, "
            f"no online placement within {s.online_ratio:.3f}" for s in shown))
    worst = sorted(rep.scenarios, key=lambda s: -s.ratio_lower_bound)[:5]
    if worst:
        console.print("Worst scenarios: " + "; ".join(
            f"{s.name} ({s.robots} robots, {s.origins} origins, {s.programs} programs): "
            f"{s.ratio_lower_bound:.3f} of the bound, {s.ratio_oracle:.3f} of the oracle" for s in worst))
