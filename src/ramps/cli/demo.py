"""``ramps demo``: the main job, a team of real nodes on this machine running the paper's scenario.

The work is done by ``ramps.bench.demo``; this module parses and
prints (rules in ``ramps.cli.common``).
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import TYPE_CHECKING, Optional

import msgspec
import typer
from rich.progress import BarColumn, MofNCompleteColumn, TaskID, TextColumn, TimeElapsedColumn

from ramps.cli.common import err, fail, out

if TYPE_CHECKING:
    from ramps.bench.demo import DemoReport


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

    from ramps.bench.demo import DEMO_ROUTE, run_demo
    from ramps.programs.route import ROUTE_SIZES

    sizes = {"demo": DEMO_ROUTE, **ROUTE_SIZES}
    if size not in sizes:
        fail(f"unknown size {size!r}; choose one of {', '.join(sizes)}")
    from ramps.extras import MissingExtra, require

    try:  # the `demo` extra (`make demo` installs it)
        require("ortools", "ramps demo (its route_plan programs)", "demo")
        require("matplotlib", "ramps demo (its report)", "demo")
    except MissingExtra as exc:
        fail(str(exc))
    progress = _Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                         TextColumn("{task.fields[spread]}"), console=err, transient=not as_json)
    tasks: dict[str, TaskID] = {}

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
    _print_report(rep)


def _print_report(rep: DemoReport) -> None:
    """The demo's result: its workload, a table of its placements side by side, what went wrong."""
    from rich.table import Table

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
            err.print(f"{ph.name}: {e}", style="red", markup=False, highlight=False, soft_wrap=True)
    if rep.report:
        out.print(f"report of the ramps run: {rep.report} (open it in a browser); the nodes' trace of the whole "
                  f"session, warm-up and baselines included: {rep.trace} (`ramps report {rep.trace}`)",
                  highlight=False, soft_wrap=True)
