"""Pictures of a run (matplotlib, Agg backend: no display needed).

How this works: each function takes data (a ``Timeline``, or experiment
reports) and returns a matplotlib ``Figure``; ``save_png`` writes one. The
run figures:

- ``gantt``: one band per robot, a bar per attempt of a program from its
  placement to its end (a thin pale start while offered, solid once
  accepted), coloured by how it ended; a cross where the origin wrote an
  attempt off (the detection, with its reason), a red line where the
  simulator struck a fault, an arrow from a written-off attempt to the
  program's next placement (the move);
- ``load``: programs running on each robot over time;
- ``distribution``: programs delivered per robot.

Rules: no decisions, no I/O besides ``save_png``; figures are closed by the
caller (``save_png`` does).
"""

from __future__ import annotations

import io
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.artist import Artist  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.lines import Line2D  # noqa: E402
from matplotlib.patches import Patch  # noqa: E402

from ramps.observe.timeline import Timeline  # noqa: E402

OUTCOME_COLOURS = {"delivered": "#2e7d32", "failed": "#c62828", "rejected": "#ef6c00", "cancelled": "#9e9e9e",
                   "running": "#1565c0", "error": "#6a1b9a", "finished": "#81c784"}
FAULT_COLOURS = {"crash": "#b71c1c", "network": "#e65100", "freeze": "#4a148c", "recover": "#1b5e20"}


def _short(pid: str, origins: int = 1) -> str:
    """A bar's label: the program's number, with its origin when several robots submitted."""
    n = pid.rsplit("-", 1)[-1] if "-" in pid else pid.split("#")[-1]
    return f"{pid.split('#')[0]}:{n}" if origins > 1 and "#" in pid else n


def gantt(tl: Timeline, *, title: str = "") -> Figure:
    bands: dict[str, tuple[float, int]] = {}  # robot -> (y of its first lane, lanes)
    y = 0.0
    for r in reversed(tl.robots):
        lanes = max((a.lane for a in tl.attempts if a.host == r), default=-1) + 1
        bands[r] = (y, max(1, lanes))
        y += max(1, lanes) + 0.8
    height = min(16.0, 1.8 + 0.22 * y)
    fig, ax = plt.subplots(figsize=(12, height))
    end = max(tl.end, 1e-6)
    few = len(tl.attempts) <= 60
    origins = len({a.origin for a in tl.attempts})
    for r, (y0, lanes) in bands.items():
        ax.axhspan(y0 - 0.45, y0 + lanes - 0.55, color="#f5f5f5" if tl.robots.index(r) % 2 else "#ffffff", zorder=0)
    for a in tl.attempts:
        y0, _ = bands[a.host]
        yy = y0 + a.lane
        stop = a.end if a.end is not None else end
        colour = OUTCOME_COLOURS.get(a.outcome, "#1565c0")
        run_from = a.accepted if a.accepted is not None else stop
        if run_from > a.start:  # offered, not yet accepted
            ax.barh(yy, run_from - a.start, left=a.start, height=0.3, color=colour, alpha=0.35, zorder=2)
        if stop > run_from:
            ax.barh(yy, stop - run_from, left=run_from, height=0.7, color=colour, zorder=2,
                    hatch="//" if a.attempt > 1 else None, edgecolor="white" if a.attempt > 1 else None, linewidth=0)
        if few:
            ax.text(max(a.start, run_from) + end * 0.003, yy, f"{_short(a.program_id, origins)}"
                    + (f".{a.attempt}" if a.attempt > 1 else ""), va="center", fontsize=6, color="white"
                    if stop - run_from > end * 0.03 else "black", zorder=4)
        if a.outcome == "failed":
            ax.plot([stop], [yy], marker="x", color="black", markersize=7, mew=2, zorder=5)
    labelled = set()
    for t, _origin, host, reason in tl.detections:  # one label per host and moment
        key = (host, round(t, 1))
        if host in bands and key not in labelled:
            labelled.add(key)
            y0, _ = bands[host]
            ax.text(t + end * 0.004, y0 - 0.42, f"written off {t:.2f} s ({reason})", fontsize=7, va="bottom",
                    color="black", zorder=6)
    for prev, nxt in tl.replacements():
        if prev.end is None:
            continue
        y1 = bands[prev.host][0] + prev.lane
        y2 = bands[nxt.host][0] + nxt.lane
        ax.annotate("", xy=(nxt.start, y2), xytext=(prev.end, y1), zorder=3,
                    arrowprops=dict(arrowstyle="->", color="#555555", lw=0.8, alpha=0.8,
                                    connectionstyle="arc3,rad=0.15"))
    for f in tl.faults:
        if f.robot in bands:
            y0, lanes = bands[f.robot]
            c = FAULT_COLOURS.get(f.kind, "black")
            ax.plot([f.t, f.t], [y0 - 0.5, y0 + lanes - 0.5], color=c, lw=2.5, zorder=6)
            ax.text(f.t, y0 + lanes - 0.45, f" {f.kind} {f.t:.1f} s", color=c, fontsize=8, va="bottom",
                    fontweight="bold", zorder=6)
    ax.set_yticks([y0 + (lanes - 1) / 2 for y0, lanes in bands.values()])
    ax.set_yticklabels(list(bands))
    ax.set_ylim(-0.8, y)
    ax.set_xlim(0, end * 1.01)
    ax.set_xlabel("seconds")
    ax.set_title(title or "where every program ran (one bar per attempt)", loc="left", fontsize=11)
    handles: list[Artist] = [Patch(color=OUTCOME_COLOURS[k], label=k)
                             for k in ("delivered", "finished", "failed", "cancelled", "running")
                             if any(a.outcome == k for a in tl.attempts)]
    handles.append(Patch(facecolor="#888888", hatch="//", edgecolor="white", label="re-placed attempt"))
    handles.append(Line2D([], [], marker="x", color="black", lw=0, label="written off (detected)"))
    if tl.faults:
        handles.append(Line2D([], [], color=FAULT_COLOURS["crash"], lw=2.5, label="fault"))
    ax.legend(handles=handles, loc="upper center", bbox_to_anchor=(0.5, -0.07 * 12 / max(height, 3)),
              fontsize=8, ncol=len(handles), frameon=False)
    ax.grid(axis="x", alpha=0.3)
    fig.tight_layout()
    return fig


def load(tl: Timeline, *, title: str = "") -> Figure:
    pts = tl.load()
    n = max(1, len(tl.robots))
    fig, axes = plt.subplots(n, 1, figsize=(12, 0.4 + 0.75 * n), sharex=True, squeeze=False)
    top = max((c for r in tl.robots for _, c in pts[r]), default=1) or 1
    for ax, r in zip(axes[:, 0], tl.robots):
        xs = [t for t, _ in pts[r]]
        ys = [c for _, c in pts[r]]
        ax.fill_between(xs, ys, step="post", color="#1565c0", alpha=0.5, lw=0)
        ax.step(xs, ys, where="post", color="#1565c0", lw=1)
        for f in tl.faults:
            if f.robot == r:
                ax.axvline(f.t, color=FAULT_COLOURS.get(f.kind, "black"), lw=2)
                ax.text(f.t, top, f" {f.kind}", fontsize=7, va="top", color=FAULT_COLOURS.get(f.kind, "black"))
        ax.set_ylim(0, top * 1.15)
        ax.set_ylabel(r, rotation=0, ha="right", va="center")
        ax.set_yticks([0, top])
        ax.tick_params(labelsize=7)
        ax.grid(alpha=0.3)
    axes[0, 0].set_title(title or "load: programs running on each robot", loc="left", fontsize=11)
    axes[-1, 0].set_xlabel("seconds")
    axes[-1, 0].set_xlim(0, max(tl.end, 1e-6) * 1.01)
    fig.tight_layout(h_pad=0.2)
    return fig


def distribution(tl: Timeline, *, title: str = "") -> Figure:
    fig, ax = plt.subplots(figsize=(6, 3.2))
    robots = tl.robots
    counts = [tl.distribution.get(r, 0) for r in robots]
    bars = ax.bar(robots, counts, color="#2e7d32")
    ax.bar_label(bars, fontsize=8)
    ax.set_ylabel("programs delivered")
    ax.set_title(title or "distribution: where delivered programs ran", loc="left", fontsize=11)
    ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    return fig


def save_png(fig: Figure, path: Path, *, dpi: int = 110) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path


def png_bytes(fig: Figure, *, dpi: int = 110) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    plt.close(fig)
    return buf.getvalue()


__all__ = ["gantt", "load", "distribution", "save_png", "png_bytes"]
