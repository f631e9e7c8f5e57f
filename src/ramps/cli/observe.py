"""``ramps report`` and ``ramps top``: seeing the team.

    ramps report r1.trace.jsonl -o run.html     # timeline, load, distribution of a run
    ramps top --connect tcp/192.168.1.12:7447   # live view of the team (Ctrl-C quits)

Rules as in ``ramps.cli.common``: user mistakes end with a one-line message and exit
code 2. The work is done by ``ramps.observe``; this module parses and prints.
``register(app)`` adds report and top to the main app.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Callable, NoReturn, Optional

import typer
from rich.console import Console
from rich.markup import escape

if TYPE_CHECKING:
    import threading

    from ramps.observe.top import TopModel

_out = Console(highlight=False, soft_wrap=True)
_err = Console(stderr=True, highlight=False, soft_wrap=True)


def _fail(message: str) -> NoReturn:
    _err.print(f"[bold red]error:[/] {escape(message)}")
    raise typer.Exit(2)


def report(
    paths: list[Path] = typer.Argument(..., help="node trace files (`ramps node --trace`, JSON lines; several "
                                       "robots' files merge), one simulator result (`ramps sim run --json "
                                       "--trace`), or one experiment result (`ramps sim paper --json`, "
                                       "`ramps testbed experiment faults --out`)"),
    out_file: Optional[Path] = typer.Option(None, "--out", "-o", help="the HTML report (default: "
                                            "<first file's name>.html in this directory)"),
    png: Optional[Path] = typer.Option(None, "--png", help="also write every figure as a PNG into this directory"),
    title: str = typer.Option("", "--title", help="the report's title (default: from the run)"),
) -> None:
    """A self-contained HTML report of a run (and PNGs): a Gantt timeline of every program per robot
    (attempts, failures and when they were noticed, re-placements), each robot's load over time, and
    the distribution; or the paper's figures from experiment results."""
    from ramps.extras import MissingExtra, require
    from ramps.observe.report import ReportError, make_report, write_html, write_pngs

    try:
        require("matplotlib", "ramps report")
        rep = make_report(paths, title=title)
    except (MissingExtra, ReportError) as exc:
        _fail(str(exc))
    html_path = out_file or Path(paths[0].name.split(".")[0] + ".html")
    write_html(rep, html_path)
    pngs = write_pngs(rep, png) if png is not None else []  # every file first, then the talking
    _out.print(f"report: {html_path} ({len(rep.figures)} figures" + (
        f", {len(rep.table) - 1} events" if len(rep.table) > 1 else "") + ")")
    for line in rep.summary:
        _out.print(f"  {line[0]}: {line[1]}")
    for p in pngs:
        _out.print(f"  {p}")


def sim_paper_plot(directory: Path, experiment: str, *, policy: str, runs: int, seed: int,
                   out_file: Optional[Path]) -> None:
    """``ramps sim paper --plot DIR``: run the experiments (in parallel) and draw the paper's figures."""
    import time

    from ramps.extras import MissingExtra, require

    try:
        require("matplotlib", "ramps sim paper --plot")
    except MissingExtra as exc:
        _fail(str(exc))
    from ramps.observe.paper_plots import run_all, write_figures

    wanted = {"all": ("unloaded", "loaded", "faults"), "unloaded": ("unloaded",), "loaded": ("loaded",),
              "faults": ("faults",)}.get(experiment)
    if wanted is None:
        _fail(f"unknown experiment {experiment!r}; choose unloaded, loaded, faults or all")
    started = time.perf_counter()
    _err.print(f"running {', '.join(wanted)} ({runs} run(s) per configuration, policy {policy}) ...")
    doc = run_all(experiments=wanted, policy=policy, runs=runs, seed=seed)
    paths = write_figures(doc, directory)
    for e in ("unloaded", "loaded"):
        if e in doc:
            sm = doc[e]["summary"]
            _out.print(f"{e}: {sm['distributions']} distributions, {sm['optimal']} optimal, {sm['near_optimal']} "
                       f"near optimal, {sm['non_optimal']} non optimal; lost {sm['lost']}, duplicated "
                       f"{sm['duplicated']}")
    for f in doc.get("faults", []):
        _out.print(f"faults {f['mode']} {f['kind']}: {len(f['runs'])} run(s), lost {f['summary'].get('lost')}, "
                   f"duplicated {f['summary'].get('duplicated')}")
    if out_file is not None:
        out_file.parent.mkdir(parents=True, exist_ok=True)
        out_file.write_text(json.dumps(doc) + "\n")
        _out.print(f"saved {out_file}")
    _out.print(f"wrote {len(paths)} figures to {directory}/ in {time.perf_counter() - started:.1f} s: "
               + ", ".join(p.name for p in paths))


TEAM_HELP = "team name (env RAMPS_TEAM)"
CONNECT_HELP = "Zenoh endpoint of a teammate, e.g. tcp/192.168.1.12:7447 (repeatable; env RAMPS_CONNECT)"


def top(
    team: Optional[str] = typer.Option(None, "--team", "-t", help=TEAM_HELP),
    connect: Optional[list[str]] = typer.Option(None, "--connect", "-c", help=CONNECT_HELP),
    multicast: Optional[bool] = typer.Option(None, "--multicast/--no-multicast", help="find the team by UDP multicast"),
    secure: bool = typer.Option(False, "--secure", help="secured team: TLS and team certificates (env RAMPS_SECURE)"),
    credentials: Optional[Path] = typer.Option(None, "--credentials", help="credentials directory from `ramps team "
                                               "add` (env RAMPS_CREDENTIALS)"),
    interval: float = typer.Option(0.25, "--interval", min=0.05, max=5.0, help="seconds between refreshes"),
    frames: int = typer.Option(0, "--frames", min=0, help="print this many frames, one per interval, then exit "
                               "(no live screen: for logs and scripts)"),
    once: bool = typer.Option(False, "--once", help="print one frame after --wait seconds and exit"),
    wait: float = typer.Option(2.5, "--wait", min=0.0, help="with --once: seconds to listen first"),
    gone_after: float = typer.Option(10.0, "--exit-after", min=0.5, help="exit when no robot has been alive for "
                                     "this many seconds (the team disappeared)"),
    events: int = typer.Option(12, "--events", min=1, max=200, help="recent events shown"),
) -> None:
    """A live view of the team: every robot with its cores, speed, CPU, run queue, programs running
    and in flight, free memory, whom it sees and whom it wrote off, and a scrolling list of events
    (robots joining and leaving, programs starting, finishing and moving). Robots that disappear
    stay, greyed, with how long ago they were last heard: "left" when the robot's node stopped
    (Ctrl-C, SIGTERM: it handed its programs back), "gone" when its liveliness went without a
    word (a crash, a cut link). Ctrl-C quits."""
    import signal
    import threading
    import time

    from ramps.errors import ConfigError, RampsError
    from ramps.observe.top import TopModel
    from ramps.runtime.client import Team
    from ramps.runtime.settings import load_settings

    try:
        s = load_settings(flags={"team": team, "connect": connect or None, "multicast": multicast,
                                 "secure": secure or None, "credentials": str(credentials) if credentials else None},
                          default_robot=False)
        t = Team(s, robot=None, timeout=5.0, submits=False)
    except (ConfigError, RampsError) as exc:
        _fail(str(exc))
    model = TopModel(t.team)
    last_alive = time.monotonic()
    reason = ""

    def step() -> bool:
        nonlocal last_alive, reason
        now = time.monotonic()
        model.update(t.status(), now)
        if model.alive():
            last_alive = now
        elif now - last_alive >= gone_after:
            reason = f"team {model.team} gone: no robot alive for {gone_after:g} s"
            return False
        return True

    # Ctrl-C sets a flag the loop reads between frames: a KeyboardInterrupt raised at any
    # instant could land while the client holds its lock, and its close() then waits forever
    stop = threading.Event()
    previous = signal.signal(signal.SIGINT, lambda *_: stop.set())
    try:
        if once or frames:
            _print_frames(model, step, stop, once=once, frames=frames, wait=wait, interval=interval, events=events)
        else:
            _live(model, step, stop, interval=interval, events=events)
    finally:
        signal.signal(signal.SIGINT, previous)
        t.close()
    if stop.is_set():
        reason = "interrupted"
    if reason:
        _err.print(reason)


def _print_frames(model: TopModel, step: Callable[[], bool], stop: threading.Event, *, once: bool, frames: int,
                  wait: float, interval: float, events: int) -> None:
    """``ramps top --frames N``: N frames printed one after another, ``interval`` apart;
    ``--once``: one frame after listening ``wait`` seconds. Fewer when the team is gone or Ctrl-C."""
    import time

    from ramps.observe.top import render

    if once:
        stop.wait(wait)
    for i in range(1 if once else frames):
        going = step()
        _out.print(render(model, time.monotonic(), events=events))
        if not going or stop.is_set():
            break
        if i + 1 < frames:
            stop.wait(interval)


def _live(model: TopModel, step: Callable[[], bool], stop: threading.Event, *, interval: float,
          events: int) -> None:
    """``ramps top``: one frame redrawn in place every ``interval`` until the team is gone or Ctrl-C."""
    import time

    from rich.live import Live

    from ramps.observe.top import render

    with Live(render(model, time.monotonic(), events=events, interval=interval), console=_out,
              refresh_per_second=max(2.0, 1 / interval), transient=False) as live:
        while not stop.is_set() and step():
            live.update(render(model, time.monotonic(), events=events, interval=interval))
            stop.wait(interval)
        live.update(render(model, time.monotonic(), events=events, interval=interval))


def register(app: typer.Typer) -> None:
    app.command("report")(report)
    app.command("top")(top)


__all__ = ["register"]
