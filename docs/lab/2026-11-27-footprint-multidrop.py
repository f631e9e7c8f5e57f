"""Several teammates cut off at once on the testbed: how long survivors go without hearing each other
(docs/lab/2026-11-27-footprint.md). As root, from the repository root:
ZENOH_RUNTIME="(rx: (worker_threads: 4))" .venv/bin/python docs/lab/2026-11-27-footprint-multidrop.py 7 4

Adapted from tests/test_testbed_faults.py::test_teammates_keep_hearing_each_other_when_one_drops_off.
ZENOH_RUNTIME from the environment (the nodes inherit it)."""
import os, sys, time
from pathlib import Path
sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "tests"))
os.environ["RAMPS_TRACE_WIRE"] = "1"
import msgspec
from ramps.testbed import Testbed
from ramps.lab.experiments import read_trace
from test_testbed import wait_until

def trace(tb, robot):
    return [msgspec.structs.asdict(e) for e in read_trace(tb.log_dir / f"{robot}.trace.jsonl")]

n, k = int(sys.argv[1]), int(sys.argv[2])
robots = [f"r{i}" for i in range(1, n + 1)]
survivors, victims = robots[:n - k], robots[n - k:]
window = 9.0
with Testbed(n, cores=1) as tb, tb.client("r1", timeout=30.0) as team:
    futures = [team.options(work=1.0).submit("burn", units=1.0) for _ in range(2 * n)]
    wait_until(lambda: sum(1 for e in trace(tb, "r1") if e["what"] == "accepted" and e["other"] in victims) >= k, 30)
    time.sleep(1.0)
    t_cut = time.monotonic()
    for v in victims:
        tb.cut(v)
    time.sleep(window)
    gaps = {}
    for rcv in survivors:
        tr = trace(tb, rcv)
        for snd in survivors:
            if snd == rcv:
                continue
            heard = [e["t"] for e in tr if e["what"] == "rx" and e["other"] == snd and t_cut <= e["t"] <= t_cut + window]
            edges = [t_cut, *sorted(heard), t_cut + window]
            gaps[f"{snd}->{rcv}"] = round(max(b - a for a, b in zip(edges, edges[1:])), 2)
    written_off = sorted({e["other"] for e in trace(tb, "r1") if e["what"] == "blacklisted"})
    print("ZENOH_RUNTIME", os.environ.get("ZENOH_RUNTIME"), "n", n, "cut", victims, "max gap", max(gaps.values()),
          "gaps>3s", {g: v for g, v in gaps.items() if v >= 3.0}, "written off by r1", written_off, flush=True)
    for f in futures:
        try:
            f.result(timeout=240)
        except Exception as e:
            print("program", type(e).__name__)
