"""The paper's figures, ours beside the paper's own values (``ramps sim paper --plot DIR``).

How this works: ``run_all`` runs the paper's experiments in the simulator
(``ramps.experiments.paper`` and ``ramps.experiments.faults``, the same
functions and seeds as ``ramps sim paper``), one configuration per task on
a process pool, so the whole set takes seconds. The plotting functions take
the JSON form of the reports (what ``ramps sim paper --json`` and ``ramps
testbed experiment faults --out`` write) so the same figures come from a
saved result, from the simulator or from the testbed:

- ``unloaded_makespan`` (Figs 3a and 4): makespan against programs for
  ramps, round robin and a single robot, one panel per team size; the
  paper's measured times (5 robots) drawn beside ours;
- ``unloaded_spread`` (Table 3): the spread (most minus fewest programs on
  a robot) of ours and the paper's distributions;
- ``loaded_makespan`` (Figs 5-6): ramps, round robin, a single robot and
  the best the model allows, one panel per number of loaded robots (the
  paper's times are only in its figures, not in its text: not drawn);
- ``loaded_share`` (Table 4): programs placed on loaded robots, ours and
  the paper's;
- ``fault_distributions`` (Tables 5-10): the mean distribution after each
  failure, ours and the paper's, for one kind of failure.

The paper's tables are transcribed below from its text (section 4-5).
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING

import msgspec

from ramps.experiments.paper import PAPER_5_ROBOTS

if TYPE_CHECKING:
    from matplotlib.figure import Figure

# ---------------------------------------------------------------- the paper's tables
#: Table 3 (median run): (programs, team size) -> distribution R1..Rn
PAPER_TABLE3 = {
    (5, 5): [1, 1, 1, 1, 1], (5, 4): [1, 2, 1, 1], (5, 3): [1, 2, 2], (5, 2): [2, 3],
    (10, 5): [1, 2, 3, 2, 2], (10, 4): [2, 3, 2, 3], (10, 3): [3, 4, 3], (10, 2): [5, 5],
    (15, 5): [2, 3, 3, 3, 4], (15, 4): [3, 4, 4, 4], (15, 3): [4, 5, 6], (15, 2): [7, 8],
    (20, 5): [3, 4, 4, 5, 4], (20, 4): [4, 5, 5, 6], (20, 3): [7, 6, 7], (20, 2): [8, 12],
    (25, 5): [4, 6, 5, 5, 5], (25, 4): [5, 6, 8, 6], (25, 3): [9, 10, 6], (25, 2): [11, 14],
    (30, 5): [7, 5, 6, 6, 6], (30, 4): [7, 9, 9, 5], (30, 3): [9, 10, 11], (30, 2): [15, 15],
}
#: Table 4 (mean of 3 runs, 5 robots, the last ``loaded`` ones busy): (programs, loaded) -> R1..R5
PAPER_TABLE4: dict[tuple[int, int], list[float]] = {
    (5, 1): [0.67, 1.34, 1.34, 1.67, 0], (5, 2): [1, 2, 2, 0, 0], (5, 3): [2.33, 2.67, 0, 0, 0],
    (5, 4): [3.67, 0.67, 0.33, 0.33, 0],
    (10, 1): [1.67, 3.33, 3, 2, 0], (10, 2): [3, 3.67, 3.33, 0, 0], (10, 3): [4, 5.67, 0, 0, 0.33],
    (10, 4): [6.67, 1, 0.67, 1, 0.67],
    (15, 1): [3, 4.33, 3.33, 4.33, 0], (15, 2): [3, 4, 6.33, 1, 0.67], (15, 3): [5.33, 5.67, 1.67, 0.67, 1.67],
    (15, 4): [6.67, 2.33, 2, 2, 2],
    (20, 1): [4, 5, 4.33, 5.33, 1.33], (20, 2): [5.33, 6.33, 5.67, 1.67, 1], (20, 3): [7.67, 7.67, 1.33, 1.33, 2],
    (20, 4): [8.67, 2.33, 3, 3, 3],
    (25, 1): [5.67, 6.33, 6, 5.33, 1.67], (25, 2): [5.33, 7.33, 7.33, 2.33, 2.67],
    (25, 3): [8.33, 9, 2.33, 2.33, 2.33], (25, 4): [8.67, 4, 4.33, 3.67, 4.33],
    (30, 1): [6.67, 7, 7, 7.33, 2], (30, 2): [6.67, 8, 7.67, 3.67, 4], (30, 3): [9.67, 12.67, 1.67, 2.67, 3.33],
    (30, 4): [8.33, 5, 5.67, 5.33, 5.67],
}
#: Table 4's rows that do not add up to their programs in the paper itself: 25 programs with 3
#: loaded robots reads 8.33, 9, 2.33, 2.33, 2.33 (24.32); drawn as printed
PAPER_TABLE4_AS_PRINTED = {(25, 3)}
_SEQ = {  # Tables 5, 7, 9: three runs, D1..D5 (surviving robots, R1 first)
    "crash": [[[3, 3, 3, 3, 3], [3, 4, 4, 4], [4, 6, 5], [7, 8], [15]],
              [[2, 3, 3, 3, 4], [4, 3, 3, 5], [5, 4, 6], [9, 6], [15]],
              [[2, 3, 4, 3, 3], [4, 3, 4, 4], [4, 6, 5], [7, 8], [15]]],
    "network": [[[3, 3, 3, 3, 3], [4, 3, 4, 4], [5, 5, 5], [9, 6], [15]],
                [[2, 3, 3, 4, 3], [4, 3, 4, 4], [4, 5, 6], [8, 7], [15]],
                [[3, 4, 3, 3, 2], [3, 4, 4, 4], [5, 5, 5], [7, 8], [15]]],
    "mixed": [[[2, 4, 3, 3, 3], [3, 4, 4, 4], [6, 5, 4], [7, 8], [15]],
              [[3, 3, 3, 3, 3], [3, 4, 4, 4], [5, 4, 6], [6, 9], [15]],
              [[3, 3, 3, 3, 3], [4, 4, 4, 3], [5, 5, 5], [8, 7], [15]]],
}
#: sequential: mean over the paper's 3 runs, D1..D5
PAPER_SEQUENTIAL = {k: [[round(statistics.fmean(run[d][i] for run in runs), 2) for i in range(len(runs[0][d]))]
                        for d in range(5)] for k, runs in _SEQ.items()}
#: Tables 6, 8, 10: mean distribution before, then after R5 / R4-R5 / R3-R5 / R2-R5 failed together
PAPER_SIMULTANEOUS: dict[str, list[list[float]]] = {
    "crash": [[2.67, 3, 3.25, 3.08, 3], [3.67, 3.67, 3.67, 4], [5, 5.33, 4.67], [7.33, 7.67], [15]],
    "network": [[2.92, 3.08, 3, 3.08, 2.92], [3.33, 3.67, 4, 4], [4.33, 5.33, 5.33], [7, 8], [15]],
    "mixed": [[3, 2.92, 2.92, 3.25, 2.92], [3.67, 4, 4, 3.33], [4.33, 5.67, 5], [7.33, 7.67], [15]],
}
ROBOTS = ["R1", "R2", "R3", "R4", "R5"]
OURS, PAPER = "#1565c0", "#ef6c00"


# ---------------------------------------------------------------- running
def _config_task(args):
    from ramps.experiments.paper import PaperSetup, run_config

    size, n, loaded, policy, runs, seed = args
    return msgspec.json.encode(run_config(size, n, loaded, policy=policy, runs=runs, seed=seed, setup=PaperSetup()))


def _fault_task(args):
    from ramps.experiments.faults import run_fault_experiment

    mode, kind, policy, runs, seed = args
    return msgspec.json.encode(run_fault_experiment(mode, kind, policy=policy, runs=runs, seed=seed))


def run_all(*, experiments=("unloaded", "loaded", "faults"), policy: str = "ramps", runs: int = 3, seed: int = 0,
            workers: int | None = None) -> dict:
    """The experiments' reports as JSON-ready dicts: {"unloaded": ..., "loaded": ..., "faults": [...]}.
    Same configurations and seeds as ``ramps sim paper``, run ``workers`` at a time (default: CPUs)."""
    import os

    from ramps.experiments.paper import ConfigRecord, ExperimentReport, PaperSetup, configurations, summarise

    started = time.perf_counter()
    out: dict = {}
    with ProcessPoolExecutor(max_workers=workers or os.cpu_count() or 1) as pool:
        jobs = {}
        for e in experiments:
            if e in ("unloaded", "loaded"):
                jobs[e] = pool.map(_config_task, [(s, n, l, policy, runs, seed) for s, n, l in configurations(e)])
        faults = None
        if "faults" in experiments:
            faults = pool.map(_fault_task, [(m, k, policy, runs, seed) for m in ("sequential", "simultaneous")
                                            for k in ("crash", "network", "mixed")])
        for e, results in jobs.items():
            configs = [msgspec.json.decode(b, type=ConfigRecord) for b in results]
            rep = ExperimentReport(experiment=e, policy=policy, runs=runs, seed=seed, setup=PaperSetup(),
                                   configs=configs, summary=summarise(configs))
            out[e] = msgspec.to_builtins(rep)
        if faults is not None:
            out["faults"] = [msgspec.json.decode(b) for b in faults]
    out["wall_seconds"] = time.perf_counter() - started
    return out


def split_documents(doc) -> dict:
    """Reports of any saved form (one report, ``{"experiments": [...]}``, or ``run_all``'s) by kind."""
    items = doc.get("experiments", [doc]) if isinstance(doc, dict) else list(doc)
    if isinstance(doc, dict) and ("unloaded" in doc or "loaded" in doc or "faults" in doc) and "experiment" not in doc:
        items = [doc[k] for k in ("unloaded", "loaded") if k in doc] + list(doc.get("faults", []))
    out: dict = {"faults": []}
    for it in items:
        if it.get("experiment") == "faults":
            out["faults"].append(it)
        elif it.get("experiment") in ("unloaded", "loaded"):
            out[it["experiment"]] = it
    return out


# ---------------------------------------------------------------- figures
def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def unloaded_makespan(rep: dict) -> Figure:
    plt = _plt()
    sizes = sorted({c["team_size"] for c in rep["configs"]})
    fig, axes = plt.subplots(1, len(sizes), figsize=(3.6 * len(sizes), 3.6), sharey=True, squeeze=False)
    for ax, size in zip(axes[0], sizes):
        cs = sorted((c for c in rep["configs"] if c["team_size"] == size), key=lambda c: c["programs"])
        xs = [c["programs"] for c in cs]
        ax.plot(xs, [c["median_makespan"] for c in cs], "o-", color=OURS, label=f"{rep['policy']} (ours)")
        ax.plot(xs, [c["median_round_robin"] for c in cs], "s-", color="#2e7d32", label="round robin (ours)")
        ax.plot(xs, [c["median_single"] for c in cs], "^-", color="#757575", label="1 robot (ours)")
        if size == 5:
            px = sorted(PAPER_5_ROBOTS["ramps"])
            ax.plot(px, [PAPER_5_ROBOTS["ramps"][x] for x in px], "o--", color=PAPER, mfc="none",
                    label="RAMPs (paper)")
            ax.plot(px, [PAPER_5_ROBOTS["round_robin"][x] for x in px], "s--", color="#a5d6a7", mfc="none",
                    label="round robin (paper)")
            ax.plot(px, [PAPER_5_ROBOTS["single"][x] for x in px], "^--", color="#bdbdbd", mfc="none",
                    label="1 robot (paper)")
        ax.set_title(f"{size} robots", fontsize=10)
        ax.set_xlabel("programs")
        ax.grid(alpha=0.3)
    axes[0, 0].set_ylabel("makespan, s (median of runs)")
    handles, labels = axes[0, -1].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=6, fontsize=8, frameon=False)
    fig.suptitle(f"Unloaded team (Figs 3a, 4): makespan against programs, {rep['runs']} run(s) each; "
                 "the paper's times are for 5 robots", fontsize=11, x=0.01, ha="left")
    fig.tight_layout(rect=(0, 0.08, 1, 0.95))
    return fig


def unloaded_spread(rep: dict) -> Figure:
    plt = _plt()
    sizes = sorted({c["team_size"] for c in rep["configs"]})
    fig, axes = plt.subplots(1, len(sizes), figsize=(3.6 * len(sizes), 3.2), sharey=True, squeeze=False)
    for ax, size in zip(axes[0], sizes):
        cs = sorted((c for c in rep["configs"] if c["team_size"] == size), key=lambda c: c["programs"])
        xs = [c["programs"] for c in cs]
        ours = []
        for c in cs:
            run = sorted(c["runs"], key=lambda r: r["makespan"])[len(c["runs"]) // 2]
            ours.append(max(run["distribution"]) - min(run["distribution"]))
        paper = [max(PAPER_TABLE3[(x, size)]) - min(PAPER_TABLE3[(x, size)]) for x in xs]
        w = 1.3
        ax.bar([x - w for x in xs], ours, width=w * 1.9 / 2, color=OURS, label="ours (median run)")
        ax.bar([x + w / 100 for x in xs], paper, width=w * 1.9 / 2, color=PAPER, label="paper (Table 3)")
        ax.axhline(1, color="black", ls=":", lw=1, label="as even as identical programs allow (<= 1 apart)")
        ax.set_xticks(xs)
        ax.set_title(f"{size} robots", fontsize=10)
        ax.set_xlabel("programs")
        ax.grid(axis="y", alpha=0.3)
    axes[0, 0].set_ylabel("most - fewest programs on a robot")
    handles, labels = axes[0, -1].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=3, fontsize=8, frameon=False)
    fig.suptitle("Unloaded team (Table 3): how uneven the distributions are", fontsize=11, x=0.01, ha="left")
    fig.tight_layout(rect=(0, 0.08, 1, 0.95))
    return fig


def loaded_makespan(rep: dict) -> Figure:
    plt = _plt()
    loads = sorted({c["loaded"] for c in rep["configs"]})
    fig, axes = plt.subplots(1, len(loads), figsize=(3.6 * len(loads), 3.6), sharey=True, squeeze=False)
    for ax, k in zip(axes[0], loads):
        cs = sorted((c for c in rep["configs"] if c["loaded"] == k), key=lambda c: c["programs"])
        xs = [c["programs"] for c in cs]
        ax.plot(xs, [c["median_makespan"] for c in cs], "o-", color=OURS, label=f"{rep['policy']} (ours)")
        ax.plot(xs, [c["median_round_robin"] for c in cs], "s-", color="#2e7d32", label="round robin (ours)")
        ax.plot(xs, [c["median_single"] for c in cs], "^-", color="#757575", label="1 robot (ours)")
        ax.plot(xs, [c["runs"][0]["optimum_makespan"] for c in cs], ":", color="black", label="best the model allows")
        ax.set_title(f"{k} loaded robot{'s' if k > 1 else ''} ({cs[0]['pattern']})", fontsize=10)
        ax.set_xlabel("programs")
        ax.grid(alpha=0.3)
    axes[0, 0].set_ylabel("makespan, s (median of runs)")
    handles, labels = axes[0, -1].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=4, fontsize=8, frameon=False)
    fig.suptitle("Loaded team of 5 (Figs 5a, 6): makespan against programs (the paper gives these times only "
                 "as figures)", fontsize=11, x=0.01, ha="left")
    fig.tight_layout(rect=(0, 0.08, 1, 0.95))
    return fig


def loaded_share(rep: dict) -> Figure:
    plt = _plt()
    loads = sorted({c["loaded"] for c in rep["configs"]})
    fig, axes = plt.subplots(1, len(loads), figsize=(3.6 * len(loads), 3.2), sharey=True, squeeze=False)
    for ax, k in zip(axes[0], loads):
        cs = sorted((c for c in rep["configs"] if c["loaded"] == k), key=lambda c: c["programs"])
        xs = [c["programs"] for c in cs]
        ours = [sum(c["mean_distribution"][5 - k:]) / c["programs"] for c in cs]
        paper = [sum(PAPER_TABLE4[(x, k)][5 - k:]) / x for x in xs]
        ax.bar([x - 1.3 for x in xs], ours, width=1.25, color=OURS, label="ours (mean of runs)")
        ax.bar([x for x in xs], paper, width=1.25, color=PAPER, label="paper (Table 4)")
        ax.set_xticks(xs)
        ax.set_title(f"{k} loaded ({cs[0]['pattern']})", fontsize=10)
        ax.set_xlabel("programs")
        ax.grid(axis="y", alpha=0.3)
    axes[0, 0].set_ylabel("share of programs on loaded robots")
    handles, labels = axes[0, -1].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=2, fontsize=8, frameon=False)
    fig.suptitle("Loaded team (Table 4): programs placed on robots that run 8 busy processes", fontsize=11,
                 x=0.01, ha="left")
    fig.tight_layout(rect=(0, 0.08, 1, 0.95))
    return fig


def _mean_dists(reports: list[dict], mode: str, kind: str) -> list[list[float]] | None:
    """Our mean distributions in the paper's order: sequential D1..D5; simultaneous
    before, then after R5 / R4-R5 / R3-R5 / R2-R5."""
    rep = next((r for r in reports if r["mode"] == mode and r["kind"] == kind), None)
    if rep is None:
        return None
    if mode == "sequential":
        labels = ["D1", "D2", "D3", "D4", "D5"]
        return [[statistics.fmean(run["distributions"][d].get(r, 0) for run in rep["runs"]) for r in ROBOTS[:5 - i]]
                for i, d in enumerate(labels)]
    befores = [run["distributions"]["before"] for run in rep["runs"]]
    out = [[statistics.fmean(b.get(r, 0) for b in befores) for r in ROBOTS]]
    for k in range(1, 5):
        runs = [run for run in rep["runs"] if run["plan"].count(",") == k - 1]
        out.append([statistics.fmean(run["distributions"]["after"].get(r, 0) for run in runs) if runs else 0.0
                    for r in ROBOTS[:5 - k]])
    return out


def fault_distributions(reports: list[dict], kind: str) -> Figure:
    plt = _plt()
    fig, axes = plt.subplots(2, 5, figsize=(15, 5.4), sharey=True)
    tables = {"crash": ("5", "6"), "network": ("7", "8"), "mixed": ("9", "10")}[kind]
    for row, (mode, paper, labels) in enumerate((
            ("sequential", PAPER_SEQUENTIAL[kind], ["D1 (none failed)", "D2: R5 failed", "D3: R4 too",
                                                    "D4: R3 too", "D5: R2 too"]),
            ("simultaneous", PAPER_SIMULTANEOUS[kind], ["before", "R5 fails", "R4, R5 fail together",
                                                        "R3-R5 together", "R2-R5 together"]))):
        ours = _mean_dists(reports, mode, kind)
        for col in range(5):
            ax = axes[row, col]
            robots = ROBOTS[:5 - col]
            xs = list(range(len(robots)))
            if ours is not None:
                ax.bar([x - 0.2 for x in xs], ours[col], width=0.4, color=OURS, label="ours (mean of runs)")
            ax.bar([x + 0.2 for x in xs], paper[col], width=0.4, color=PAPER,
                   label=f"paper (Table {tables[row]})")
            ax.set_xticks(xs)
            ax.set_xticklabels(robots)
            ax.set_title(labels[col], fontsize=9)
            ax.grid(axis="y", alpha=0.3)
        axes[row, 0].set_ylabel(f"{mode}\nprograms per robot")
    handles, labels_ = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels_, loc="lower center", ncol=2, fontsize=9, frameon=False)
    fig.suptitle(f"15 programs on 5 robots while R5, R4, R3, R2 fail ({kind}; Tables {tables[0]} and "
                 f"{tables[1]}): mean distribution after each failure", fontsize=11, x=0.01, ha="left")
    fig.tight_layout(rect=(0, 0.06, 1, 0.95))
    return fig


def _builders(doc) -> list[tuple[str, str, Callable[[], Figure]]]:
    """(name, caption, function returning the figure) for every experiment in ``doc``."""
    parts = split_documents(doc)
    out: list[tuple[str, str, Callable[[], Figure]]] = []
    if "unloaded" in parts:
        out.append(("unloaded-makespan", "Makespan on an unloaded team, ours next to the paper's measured times.",
                    lambda: unloaded_makespan(parts["unloaded"])))
        out.append(("unloaded-spread", "Unevenness of the distributions, ours next to the paper's Table 3.",
                    lambda: unloaded_spread(parts["unloaded"])))
    if "loaded" in parts:
        out.append(("loaded-makespan", "Makespan on a loaded team of 5.", lambda: loaded_makespan(parts["loaded"])))
        out.append(("loaded-share", "Programs placed on loaded robots, ours next to the paper's Table 4.",
                    lambda: loaded_share(parts["loaded"])))
    kinds = sorted({r["kind"] for r in parts["faults"]}, key=["crash", "network", "mixed"].index)
    for k in kinds:
        out.append((f"faults-{k}", f"Distributions after {k} failures, ours next to the paper's tables.",
                    partial(fault_distributions, parts["faults"], k)))
    return out


def figures(doc) -> list[tuple[str, str, Figure]]:
    """(name, caption, matplotlib figure) for every experiment in ``doc``."""
    return [(name, caption, build()) for name, caption, build in _builders(doc)]


def _write_one(args) -> str:
    doc, name, path, dpi = args
    plt = _plt()
    build = next(b for n, _, b in _builders(doc) if n == name)
    fig = build()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path


def write_figures(doc, directory: Path, *, dpi: int = 110, workers: int | None = None) -> list[Path]:
    """Every figure of ``doc`` as ``<directory>/<name>.png``, drawn ``workers`` at a time (default: CPUs)."""
    import os

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    jobs = [(doc, name, str(directory / f"{name}.png"), dpi) for name, _, _ in _builders(doc)]
    n = min(len(jobs), workers or os.cpu_count() or 1)
    if n <= 1:
        return [Path(_write_one(j)) for j in jobs]
    with ProcessPoolExecutor(max_workers=n) as pool:
        return [Path(p) for p in pool.map(_write_one, jobs)]


__all__ = ["run_all", "figures", "write_figures", "split_documents", "PAPER_TABLE3", "PAPER_TABLE4",
           "PAPER_SEQUENTIAL", "PAPER_SIMULTANEOUS"]
