"""Where one call's time goes, stage by stage, on a real loopback team.

``python -m ramps.bench.dispatchstages [--calls 300] [--policy round_robin]
[--out FILE.json]``

How this works: three real nodes (``ramps.testing.LocalTeam``, 2 cores each)
write their decisions and every message they send and receive to one trace
(``RAMPS_TRACE``, ``RAMPS_TRACE_WIRE``); a client makes ``--calls`` no-op
calls one after another, timing each on ``time.monotonic`` (one clock for
every process of a host). Each call is matched to its program by the time
the origin placed it, and cut into stages: the client's submission until
the origin placed it, the offer's way to the host, the host's acceptance,
the worker's run, the result's way back, the origin's delivery (its durable
record written first), the outcome's way to the client. A "tx" time is taken
after the put returned, an "rx" time when the transport's callback queued
the bytes. Calls that ran on the origin itself have fewer stages. Tracing
costs time too, so the totals are above ``ramps bench dispatch``'s; the
stages tell where the time goes. Printed (median and mean, microseconds)
and saved as JSON; it asserts nothing.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import sys
import tempfile
import time
from collections import defaultdict
from typing import Any

from ramps.bench.simulator import machine

#: the stages of a call that ran on another robot: (name, from, to); an
#: event is (what, the robot that traced it, detail prefix): "origin"/"host"
#: stand for those robots, None for any; "submit"/"result" are the client's clock
Point = str | tuple[str, str | None, str | None]
REMOTE: tuple[tuple[str, Point, Point], ...] = (
    ("client submit -> placed", "submit", ("placed", None, None)),
    ("placed -> offer sent", ("placed", None, None), ("tx", "origin", "OffloadRequest")),
    ("offer sent -> host heard it", ("tx", "origin", "OffloadRequest"), ("rx", "host", "OffloadRequest")),
    ("host heard it -> acceptance sent", ("rx", "host", "OffloadRequest"), ("tx", "host", "OffloadAccepted")),
    ("acceptance sent -> result sent (worker)", ("tx", "host", "OffloadAccepted"), ("tx", "host", "ProgramResult")),
    ("result sent -> origin heard it", ("tx", "host", "ProgramResult"), ("rx", "origin", "ProgramResult")),
    ("origin heard it -> delivered", ("rx", "origin", "ProgramResult"), ("delivered", None, None)),
    ("delivered -> client has it", ("delivered", None, None), "result"),
)
LOCAL: tuple[tuple[str, Point, Point], ...] = (
    ("client submit -> placed", "submit", ("placed", None, None)),
    ("placed -> delivered (worker included)", ("placed", None, None), ("delivered", None, None)),
    ("delivered -> client has it", ("delivered", None, None), "result"),
)


def _first(events: list[dict[str, Any]], what: str, robot: str | None, detail: str | None) -> float | None:
    for e in events:
        if e["what"] == what and (robot is None or e["robot"] == robot) and (
                detail is None or e["detail"].startswith(detail)):
            return float(e["t"])
    return None


def stages(calls: int = 300, policy: str = "round_robin") -> dict[str, Any]:
    """Run the calls and cut them into stages (see the module's docstring)."""
    from ramps.testing import LocalTeam

    folder = tempfile.mkdtemp(prefix="ramps-bench-stages-")
    trace = os.path.join(folder, "trace.jsonl")
    env = dict(os.environ, RAMPS_TRACE=trace, RAMPS_TRACE_WIRE="1")
    try:
        with LocalTeam(3, cores=2, speed=1.0, env=env) as team:
            client = team.client()
            try:
                time.sleep(1.5)  # every load server has heard every robot
                submit = client.options(policy=policy).submit if policy else client.submit
                for _ in range(50):
                    submit("noop").result(timeout=30)
                timed = []
                for _ in range(calls):
                    t0 = time.monotonic()
                    f = submit("noop")
                    f.result(timeout=30)
                    timed.append((t0, time.monotonic(), f.host))
                time.sleep(0.5)  # the last trace lines
            finally:
                client.close()
        with open(trace) as f:
            records = [json.loads(line) for line in f]
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    by_program: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for r in records:
        if r["program_id"]:
            by_program[r["program_id"]].append(r)
    origin = "r1"
    placed = sorted((t, pid) for pid, evs in by_program.items()
                    if (t := _first(evs, "placed", origin, None)) is not None)
    figures: dict[str, list[float]] = defaultdict(list)
    i = 0
    for t0, t1, host in timed:
        while i < len(placed) and placed[i][0] < t0:
            i += 1
        if i >= len(placed):
            break
        events = sorted(by_program[placed[i][1]], key=lambda e: e["t"])
        i += 1
        kind, table = ("local", LOCAL) if host == origin else ("remote", REMOTE)
        who = {"origin": origin, "host": host}
        row = []
        for name, start, end in table:
            ends: list[float | None] = []
            for point in (start, end):
                if isinstance(point, str):  # the client's own clock
                    ends.append(t0 if point == "submit" else t1)
                else:
                    what, robot, detail = point
                    ends.append(_first(events, what, who[robot] if robot else None, detail))
            first, last = ends
            if first is None or last is None:
                break
            row.append((name, last - first))
        else:
            for name, seconds in row:
                figures[f"{kind}: {name}"].append(seconds)
            figures[f"{kind}: total"].append(t1 - t0)
    return {"calls": calls, "policy": policy, "machine": machine(), "loadavg": list(os.getloadavg()),
            "stages": {k: {"calls": len(v), "p50_us": statistics.median(v) * 1e6, "mean_us": statistics.fmean(v) * 1e6}
                       for k, v in figures.items()}}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m ramps.bench.dispatchstages", description=__doc__.split("\n")[0])
    p.add_argument("--calls", type=int, default=300, help="no-op calls, one after another")
    p.add_argument("--policy", default="round_robin",
                   help="placement policy of the calls (round_robin: a third on the origin; '' the node's)")
    p.add_argument("--out", default="", help="also save the figures as JSON to this file")
    a = p.parse_args(argv)
    if a.calls < 1:
        p.error("--calls must be at least 1")
    res = stages(a.calls, a.policy)
    for name, v in res["stages"].items():
        print(f"{name:52s} {v['calls']:5d} calls  p50 {v['p50_us']:7.0f} us  mean {v['mean_us']:7.0f} us")
    if a.out:
        with open(a.out, "w") as f:
            json.dump(res, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
