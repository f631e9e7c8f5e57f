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
