"""``ramps report``: a self-contained HTML page (and PNGs) of a run or an experiment.

How this works: ``make_report(paths)`` recognises what it was given:

- traces (node ``--trace`` files, ``ramps sim run --json --trace``): the
  run is rebuilt as a ``Timeline`` (``ramps.observe.timeline``) and drawn as
  a Gantt chart, the load of every robot and the distribution, with a
  summary of every fault, when the origin noticed it and when the displaced
  programs ran again;
- experiment results (``ramps sim paper --json``, ``ramps testbed
  experiment faults --out``): the paper's figures (``ramps.observe.paper_plots``).

It returns a ``Report`` (title, figures, summary rows); ``write_html``
embeds the PNGs as base64 so the one file can be mailed or attached to an
issue, ``write_pngs`` writes them one by one.
"""

from __future__ import annotations

import base64
import datetime as _dt
import html
import json
from dataclasses import dataclass, field
from pathlib import Path

from ramps.observe.timeline import ReportError, Timeline, build_timeline, load_run


@dataclass
class Report:
    title: str
    #: (name, caption, png bytes)
    figures: list[tuple[str, str, bytes]] = field(default_factory=list)
    #: (label, value) pairs shown as the summary
    summary: list[tuple[str, str]] = field(default_factory=list)
    #: a table: header row, then rows
    table: list[list[str]] = field(default_factory=list)
    timeline: Timeline | None = None


def fault_summary(tl: Timeline) -> list[dict]:
    """Every fault the simulator struck: when the origin wrote the robot's
    attempts off (detection) and when the last displaced program was
    accepted elsewhere (recovery), both in seconds after the fault."""
    out = []
    for f in tl.faults:
        if f.kind == "recover":
            continue
        running = [a for a in tl.attempts if a.host == f.robot and a.start <= f.t
                   and (a.end is None or a.end >= f.t) and a.outcome in ("failed", "running", "cancelled")]
        detected = [a.end for a in running if a.outcome == "failed" and a.end is not None]
        again = []
        for a in running:
            accepted = [b.accepted for b in tl.attempts if b.program_id == a.program_id and b.attempt > a.attempt
                        and b.accepted is not None]
            if accepted:
                again.append(min(accepted))
        out.append({"robot": f.robot, "kind": f.kind, "at": f.t, "displaced": len(running),
                    "detection": min(detected) - f.t if detected else None,
                    "recovery": max(again) - f.t if running and len(again) == len(running) else None})
    return out


def run_report(tl: Timeline, *, title: str = "") -> Report:
    from ramps.observe import plots

    title = title or tl.title or "ramps run"
    rep = Report(title=title, timeline=tl)
    rep.figures.append(("timeline", "Where every program ran: one bar per attempt, from its placement (thin: "
                        "offered) to its end; crosses: attempts written off; arrows: re-placements; red "
                        "lines: faults.", plots.png_bytes(plots.gantt(tl, title=title))))
    rep.figures.append(("load", "Programs running on each robot over time.", plots.png_bytes(plots.load(tl))))
    rep.figures.append(("distribution", "Where the delivered programs ran.",
                        plots.png_bytes(plots.distribution(tl))))
    delivered = [ok for _, ok in tl.deliveries.values()]
    moved = tl.replacements()
    rep.summary = [
        ("robots", ", ".join(tl.robots)),
        ("programs", str(len({a.program_id for a in tl.attempts}))),
        ("delivered", f"{sum(delivered)} ok, {len(delivered) - sum(delivered)} with an error"),
        ("attempts", f"{len(tl.attempts)} ({len(moved)} re-placements)"),
        ("attempts written off", str(len(tl.detections))),
        ("distribution", " ".join(f"{r}:{n}" for r, n in tl.distribution.items())),
        ("last event", f"{tl.end:.2f} s"),
    ]
    rows = [["t (s)", "event", "robot", "details"]]
    for f in fault_summary(tl):
        det = "not noticed" if f["detection"] is None else f"written off after {f['detection']:.2f} s"
        rec = ("-" if not f["displaced"] else "not all ran again" if f["recovery"] is None
               else f"all running again after {f['recovery']:.2f} s")
        rows.append([f"{f['at']:.2f}", f["kind"], f["robot"], f"{f['displaced']} program(s) displaced; {det}; {rec}"])
    for t, origin, host, reason in tl.detections:
        rows.append([f"{t:.2f}", "written off", host, f"by {origin}: {reason}"])
    for prev, nxt in moved:
        rows.append([f"{nxt.start:.2f}", "re-placed", nxt.host,
                     f"{nxt.program_id} attempt {nxt.attempt} (was on {prev.host}, {prev.outcome})"])
    for t, origin, host in tl.blacklistings:
        rows.append([f"{t:.2f}", "blacklisted", host, f"by {origin}"])
    rows[1:] = sorted(rows[1:], key=lambda r: float(r[0]))
    rep.table = rows
    return rep


def experiment_report(doc, *, title: str = "") -> Report:
    """A report of saved experiment results: their summaries and the paper's
    figures (``ramps.observe.paper_plots``)."""
    from ramps.observe.paper_plots import figures, split_documents
    from ramps.observe.plots import png_bytes

    rep = Report(title=title or "ramps experiments")
    parts = split_documents(doc)
    for e in ("unloaded", "loaded"):
        if e in parts:
            s = parts[e]["summary"]
            rep.summary.append((f"{e} ({parts[e]['policy']}, {parts[e]['runs']} runs)",
                                f"{s['distributions']} distributions: {s['optimal']} optimal, {s['near_optimal']} "
                                f"near, {s['non_optimal']} non optimal; worst vs round robin "
                                f"{s['worst_ratio_to_round_robin']:.3f}"))
    for f in parts["faults"]:
        rep.summary.append((f"faults {f['mode']} {f['kind']} ({f.get('world', 'simulator')})",
                            ", ".join(f"{k} {v:.2f}" if isinstance(v, float) else f"{k} {v}"
                                      for k, v in f["summary"].items() if not isinstance(v, (dict, list)))))
    for name, caption, fig in figures(doc):
        rep.figures.append((name, caption, png_bytes(fig)))
    return rep


def make_report(paths: list[Path], *, title: str = "", window: tuple[float, float] | None = None) -> Report:
    """A report of whatever ``paths`` hold (see the module docstring);
    ``window``: of node traces, only the part between these Unix times."""
    paths = [Path(p) for p in paths]
    if len(paths) == 1:
        doc = _json_document(paths[0])
        if doc is not None and _is_experiment(doc):
            return experiment_report(doc, title=title or paths[0].name)
    events, extra = load_run(paths, window=window)
    return run_report(build_timeline(events, extra), title=title)


def _json_document(path: Path):
    try:
        text = path.read_text()
    except OSError as exc:
        raise ReportError(f"cannot read {path}: {exc.strerror or exc}") from None
    if not text.lstrip().startswith("{"):
        return None
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return None


def _is_experiment(doc) -> bool:
    return isinstance(doc, dict) and ("experiments" in doc or doc.get("experiment") in ("unloaded", "loaded", "faults")
                                      or any(k in doc for k in ("unloaded", "loaded", "faults")))


# ====================================================================== output
def write_html(rep: Report, path: Path) -> Path:
    path = Path(path)
    esc = html.escape
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>{esc(rep.title)}</title>",
             "<style>body{font-family:system-ui,sans-serif;margin:2em;max-width:1300px}"
             "table{border-collapse:collapse;font-size:13px}td,th{border:1px solid #ddd;padding:3px 8px;"
             "text-align:left}th{background:#f0f0f0}img{max-width:100%;border:1px solid #eee}"
             "figcaption{color:#555;font-size:13px;margin-bottom:1.5em}</style></head><body>",
             f"<h1>{esc(rep.title)}</h1>",
             f"<p style='color:#777'>ramps report, generated {_dt.datetime.now().isoformat(timespec='seconds')}</p>"]
    if rep.summary:
        parts.append("<table>" + "".join(f"<tr><th>{esc(k)}</th><td>{esc(v)}</td></tr>" for k, v in rep.summary)
                     + "</table>")
    for name, caption, png in rep.figures:
        b64 = base64.b64encode(png).decode()
        parts.append(f"<figure id='{esc(name)}'><img alt='{esc(name)}' src='data:image/png;base64,{b64}'>"
                     f"<figcaption>{esc(caption)}</figcaption></figure>")
    if len(rep.table) > 1:
        head, *rows = rep.table
        parts.append("<h2>Events</h2><table><tr>" + "".join(f"<th>{esc(h)}</th>" for h in head) + "</tr>")
        for r in rows[:2000]:
            parts.append("<tr>" + "".join(f"<td>{esc(c)}</td>" for c in r) + "</tr>")
        parts.append("</table>" + (f"<p>{len(rows) - 2000} more rows not shown</p>" if len(rows) > 2000 else ""))
    parts.append("</body></html>")
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(parts))
    return path


def write_pngs(rep: Report, directory: Path) -> list[Path]:
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    out = []
    for name, _caption, png in rep.figures:
        p = directory / f"{name}.png"
        p.write_bytes(png)
        out.append(p)
    return out


__all__ = ["Report", "make_report", "run_report", "experiment_report", "fault_summary", "write_html", "write_pngs",
           "ReportError"]
