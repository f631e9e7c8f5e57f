"""``ramps report`` and ``ramps sim paper --plot``: pictures of runs, checked against the traces.

The timeline a report draws is rebuilt from the trace (ramps.observe.timeline);
these tests check that data against what the simulator recorded: the crash,
when the origin wrote the crashed robot's programs off, and where and when
each displaced program ran again.
"""

from __future__ import annotations

import base64
import json
import re
import subprocess
import sys
from pathlib import Path

import msgspec
import pytest

from ramps.experiments.faults import _failure_record, plans, scenario_for
from ramps.observe import paper_plots
from ramps.observe.report import fault_summary, make_report, write_html
from ramps.observe.timeline import ReportError, build_timeline, load_run, sim_result_events
from ramps.sim.engine import Simulator

ROOT = Path(__file__).resolve().parent.parent
PNG = b"\x89PNG\r\n\x1a\n"


def ramps_cli(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "ramps.cli", *args], cwd=cwd, capture_output=True, text=True,
                          timeout=120)


@pytest.mark.slow
def test_report_of_a_simulated_crash_matches_the_trace(tmp_path):
    """examples/warehouse.yaml: r5 crashes at 20 s (25 s with the warm-up) with programs on it."""
    sim = ramps_cli("sim", "run", str(ROOT / "examples" / "warehouse.yaml"), "--json", "--trace", "-o",
                    str(tmp_path / "run.json"), cwd=tmp_path)
    assert sim.returncode == 0, sim.stderr
    doc = json.loads((tmp_path / "run.json").read_text())
    r = ramps_cli("report", str(tmp_path / "run.json"), "-o", str(tmp_path / "run.html"), "--png",
                  str(tmp_path / "png"), cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    page = (tmp_path / "run.html").read_text()
    images = re.findall(r"data:image/png;base64,([A-Za-z0-9+/=]+)", page)
    assert len(images) == 3 and all(base64.b64decode(i).startswith(PNG) for i in images)
    assert "src=\"http" not in page and "src='http" not in page  # self-contained
    assert sorted(p.name for p in (tmp_path / "png").iterdir()) == ["distribution.png", "load.png", "timeline.png"]

    tl = build_timeline(*load_run([tmp_path / "run.json"]))
    trace = doc["trace"]
    crash = [e for e in trace if e[2] == "fault"]
    assert [(f.t, f.robot, f.kind) for f in tl.faults] == [(e[0], e[1], e[6]) for e in crash]
    t_crash = tl.faults[0].t
    # the attempts on r5 at the crash end where the origin wrote them off, at the trace's "failed" times
    on_r5 = [a for a in tl.attempts if a.host == "r5" and a.start < t_crash]
    failed = {(e[3], e[5]): e[0] for e in trace if e[2] == "failed" and e[4] == "r5"}
    assert on_r5 and {(a.program_id, a.attempt): a.end for a in on_r5} == failed
    assert all(a.outcome == "failed" and a.end >= t_crash for a in on_r5)
    # each was placed again elsewhere, after the detection, where the trace says, and delivered from there
    moved = {prev.program_id: nxt for prev, nxt in tl.replacements() if prev.host == "r5"}
    assert set(moved) == {a.program_id for a in on_r5}
    accepted = {(e[3], e[5]): (e[0], e[4]) for e in trace if e[2] == "accepted"}
    for pid, nxt in moved.items():
        assert nxt.host != "r5" and nxt.start >= failed[(pid, 1)]
        assert (nxt.accepted, nxt.host) == accepted[(pid, nxt.attempt)]
        rec = next(p for p in doc["programs"] if p["program_id"] == pid)
        assert nxt.outcome == "delivered" and nxt.end == rec["delivered_at"] and rec["host"] == nxt.host
    # the fault table agrees with the fault experiments' own reading of the trace
    fs = fault_summary(tl)[0]
    from ramps.sim.engine import TraceEntry

    ref = _failure_record([TraceEntry(*e) for e in trace], t_crash, "r5", "crash",
                          {p["program_id"] for p in doc["programs"] if p["delivered_at"] and p["delivered_at"] < t_crash})
    assert fs["displaced"] == ref.displaced == len(on_r5)
    assert fs["detection"] == pytest.approx(ref.detection)
    assert fs["recovery"] == pytest.approx(ref.recovery)
    # the distribution is the simulator's
    assert tl.distribution == doc["distribution"]
    assert f"written off after {fs['detection']:.2f} s" in page


def test_timeline_of_every_sequential_crash():
    """Four robots crash one after the other: each crash's programs are written off and re-placed."""
    plan = plans("sequential", "crash", first=10.0, gap=10.0)[0]
    res = Simulator(scenario_for(plan, seed=3, policy="ramps", work=60.0), trace=True).run()
    tl = build_timeline(*sim_result_events(res))
    assert [f.robot for f in tl.faults] == ["R5", "R4", "R3", "R2"]
    for f in fault_summary(tl):
        assert f["displaced"] > 0 and f["detection"] is not None and 0 <= f["detection"] < 1.0
        assert f["recovery"] is not None and f["recovery"] >= f["detection"]
    assert sum(tl.distribution.values()) == res.completed == 15
    # no attempt on a robot outlives its crash
    crashed = {f.robot: f.t for f in tl.faults}
    for a in tl.attempts:
        if a.host in crashed and a.accepted is not None:
            assert a.start > crashed[a.host] or a.end <= crashed[a.host] + 1.0


def test_report_of_a_testbed_run_matches_its_traces(tmp_path):
    """tests/data/testbed-run: the traces of r1 and r2, both origins, from one run of `ramps testbed
    campaign` (4 emulated robots; r4 stalled and dropped off while it ran programs of both; r1's own
    driver stalled 1.6 s). Every write-off, re-placement and delivery in the timeline is where and
    when the traces put it."""
    paths = sorted((ROOT / "tests" / "data" / "testbed-run").glob("r*.trace.jsonl"))
    lines = [json.loads(x) for p in paths for x in p.read_text().splitlines()]
    t0 = min(x["wall"] for x in lines)
    tl = build_timeline(*load_run(paths))
    attempts = {(a.program_id, a.attempt): a for a in tl.attempts}
    placed = [x for x in lines if x["what"] == "placed"]
    assert len(attempts) == len(placed) and {a.origin for a in tl.attempts} == {"r1", "r2"}
    for x in placed:
        a = attempts[(x["program_id"], x["attempt"])]
        assert (a.host, a.origin, a.start) == (x["other"], x["robot"], pytest.approx(x["wall"] - t0, abs=1e-6))
    failed = [x for x in lines if x["what"] == "failed"]
    assert failed
    for x in failed:
        a = attempts[(x["program_id"], x["attempt"])]
        assert (a.outcome, a.host, a.detail) == ("failed", x["other"], x["detail"])
        assert a.end == pytest.approx(x["wall"] - t0, abs=1e-6)
        nxt = attempts[(x["program_id"], x["attempt"] + 1)]  # placed again, after the write-off
        assert nxt.start >= a.end and nxt.host != a.host
    delivered = [x for x in lines if x["what"] == "delivered"]
    for x in delivered:
        a = attempts[(x["program_id"], x["attempt"])]
        assert (a.outcome, a.host) == ("delivered", x["other"])
        assert a.end == pytest.approx(x["wall"] - t0, abs=1e-6)
    expected = {r: sum(1 for x in delivered if x["other"] == r and not x["detail"]) for r in tl.robots}
    assert tl.distribution == expected
    moved = tl.replacements()
    assert len(moved) == len(failed)
    rep = make_report(paths)
    assert [n for n, _, png in rep.figures if png.startswith(PNG)] == ["timeline", "load", "distribution"]
    assert sum(1 for row in rep.table[1:] if row[1] == "re-placed") == len(failed)


def test_bad_inputs_are_clear_errors(tmp_path):
    (tmp_path / "x.jsonl").write_text('{"t": 1}\n')
    with pytest.raises(ReportError, match="x.jsonl:1"):
        load_run([tmp_path / "x.jsonl"])
    (tmp_path / "sim.json").write_text(json.dumps({"trace": [], "programs": []}))
    with pytest.raises(ReportError, match="--trace"):
        load_run([tmp_path / "sim.json"])
    with pytest.raises(ReportError, match="cannot read"):
        load_run([tmp_path / "missing.jsonl"])


@pytest.mark.slow
def test_report_cli_bad_input_exits_2(tmp_path):
    (tmp_path / "x.jsonl").write_text('{"t": 1}\n')
    r = ramps_cli("report", str(tmp_path / "x.jsonl"), cwd=tmp_path)
    assert r.returncode == 2 and "not a ramps trace line" in r.stderr and "Traceback" not in r.stderr


def test_node_trace_lines_merge_on_wall_time(tmp_path):
    """Two robots' trace files (the format ``ramps node --trace`` writes) become one timeline."""
    rows = [
        {"t": 100.0, "wall": 5000.0, "robot": "r1", "what": "placed", "program_id": "r1#1-1", "other": "r2",
         "attempt": 1, "detail": ""},
        {"t": 100.1, "wall": 5000.1, "robot": "r1", "what": "accepted", "program_id": "r1#1-1", "other": "r2",
         "attempt": 1, "detail": ""},
        {"t": 103.0, "wall": 5003.0, "robot": "r1", "what": "failed", "program_id": "r1#1-1", "other": "r2",
         "attempt": 1, "detail": "heartbeat_timeout"},
        {"t": 104.0, "wall": 5004.0, "robot": "r1", "what": "placed", "program_id": "r1#1-1", "other": "r3",
         "attempt": 2, "detail": ""},
        {"t": 104.1, "wall": 5004.1, "robot": "r1", "what": "accepted", "program_id": "r1#1-1", "other": "r3",
         "attempt": 2, "detail": ""},
        {"t": 109.0, "wall": 5009.0, "robot": "r1", "what": "delivered", "program_id": "r1#1-1", "other": "r3",
         "attempt": 2, "detail": ""},
    ]
    (tmp_path / "r1.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    (tmp_path / "r3.jsonl").write_text(json.dumps({"t": 7.0, "wall": 5002.0, "robot": "r3", "what": "stalled",
                                                   "program_id": "", "other": "", "attempt": 0, "detail": "0.6"}) + "\n")
    tl = build_timeline(*load_run([tmp_path / "r1.jsonl", tmp_path / "r3.jsonl"]))
    a1, a2 = tl.attempts
    assert (a1.host, a1.start, a1.end, a1.outcome, a1.detail) == ("r2", 0.0, 3.0, "failed", "heartbeat_timeout")
    assert (a2.host, a2.start, a2.accepted, a2.end, a2.outcome) == ("r3", 4.0, pytest.approx(4.1), 9.0, "delivered")
    assert tl.distribution == {"r1": 0, "r2": 0, "r3": 1}
    rep = make_report([tmp_path / "r1.jsonl", tmp_path / "r3.jsonl"])
    assert [n for n, _, png in rep.figures if png.startswith(PNG)] == ["timeline", "load", "distribution"]
    write_html(rep, tmp_path / "r.html")
    assert "heartbeat_timeout" in (tmp_path / "r.html").read_text()


@pytest.mark.slow
def test_sim_paper_plot_draws_the_figures_with_the_papers_values(tmp_path):
    r = ramps_cli("sim", "paper", "-e", "unloaded", "--runs", "1", "--plot", str(tmp_path / "figs"), "-o",
                  str(tmp_path / "unloaded.json"), cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    names = sorted(p.name for p in (tmp_path / "figs").iterdir())
    assert names == ["unloaded-makespan.png", "unloaded-spread.png"]
    assert all((tmp_path / "figs" / n).read_bytes().startswith(PNG) for n in names)
    doc = json.loads((tmp_path / "unloaded.json").read_text())
    # the parallel run gives exactly what `ramps sim paper` gives, configuration by configuration
    from ramps.experiments.paper import PaperSetup, run_config

    c = doc["unloaded"]["configs"][5]
    ref = run_config(c["team_size"], c["programs"], 0, policy="ramps", runs=1, seed=0, setup=PaperSetup())
    assert c["runs"][0]["distribution"] == ref.runs[0].distribution
    assert c["runs"][0]["makespan"] == pytest.approx(ref.runs[0].makespan)
    # the saved JSON makes the same figures through `ramps report`
    assert [n for n, _, _ in make_report([tmp_path / "unloaded.json"]).figures] == ["unloaded-makespan",
                                                                                     "unloaded-spread"]


@pytest.mark.slow
def test_fault_figures_from_fault_reports():
    """The failure experiments' figures, from the reports `ramps sim paper -e faults --json` (or the testbed) saves."""
    from ramps.experiments.faults import run_fault_experiment

    reps = [msgspec.to_builtins(run_fault_experiment(m, "crash", runs=1)) for m in ("sequential", "simultaneous")]
    ours = paper_plots._mean_dists(reps, "sequential", "crash")
    assert [len(d) for d in ours] == [5, 4, 3, 2, 1] and all(sum(d) == 15 for d in ours)
    assert paper_plots._mean_dists(reps, "simultaneous", "crash")[4] == [15.0]
    figs = paper_plots.figures({"experiments": reps})
    assert [n for n, _, _ in figs] == ["faults-crash"]


def test_papers_tables_as_transcribed():
    """Sanity of the transcription: every row of Tables 3-10 sums to its number of programs."""
    for (n, _size), dist in paper_plots.PAPER_TABLE3.items():
        assert sum(dist) == n
    off = {key for key, dist in paper_plots.PAPER_TABLE4.items() if abs(sum(dist) - key[0]) > 0.05}
    assert off == paper_plots.PAPER_TABLE4_AS_PRINTED  # the paper's own row that does not add up
    for table in (paper_plots.PAPER_SEQUENTIAL, paper_plots.PAPER_SIMULTANEOUS):
        for rows in table.values():
            assert [len(r) for r in rows] == [5, 4, 3, 2, 1]
            assert all(sum(r) == pytest.approx(15, abs=0.05) for r in rows)
