"""The paper's failure experiments on the testbed, and what its experiments share.

The real-process twin of ``ramps.experiments.faults``; the other modules of
``ramps.lab`` take their shared helpers from here (``SETTLE``,
``identical_speed``, ``read_trace``, ``hosts_at``, ``_keep``).

How this works: ``run_plan`` runs one ``ramps.experiments.faults.FaultPlan``
(the same description the simulator runs) on real node processes: a fresh
five-robot ``Testbed`` (``r1``..``r5`` stand for the paper's R1..R5), 15
``burn`` programs submitted from r1 through a ``Team`` client, then each
failure at its time (``crash`` = SIGKILL, ``network`` = link down). Each
node writes its decisions to a trace file (``ramps node --trace``), in the
simulator's trace format with ``time.monotonic()`` stamps, one clock for
every process of the host; so the detection and recovery figures come from
the very function that measures the simulator (``_failure_record``):

* detection: from the fault to the origin (r1) writing the robot off;
* recovery: from the fault until every program that was running there has
  been accepted by another robot.

Distributions are where the origin has each program at the plan's snapshot
times, from its trace: accepted by a robot and neither finished nor written
off there (the origin's own record of where its programs run). Lost =
programs whose future did not complete with the right checksum; duplicated =
programs the origin delivered more than once.

The randomized fault campaign on the same set-up is ``ramps.lab.campaign``.

Work sizing: the programs must still run at the last snapshot (as in the
paper). ``work`` defaults to ``0.9 * gap`` units: with 0.4 host cores per
robot, 3 programs on a robot get 0.13 host cores each, so a program that
never moves gets at most ~0.13 * 5 * gap CPU-seconds by the last snapshot of
a sequential run (1 unit is about 1 CPU-second, see ramps.programs.burn).
"""

from __future__ import annotations

import json
import time
from concurrent.futures import wait as wait_futures
from pathlib import Path
from typing import TYPE_CHECKING, Callable

import msgspec

from ramps.experiments.faults import ROBOTS, FaultPlan, FaultRun, _failure_record
from ramps.experiments.metrics import classify_counts
from ramps.programs.burn import burn
from ramps.sim.engine import TraceEntry

if TYPE_CHECKING:
    from ramps.testbed import Testbed

#: seconds for load added to robots to be adopted, capped and reported (reports
#: come every 1 s); a testbed just up needs none: ``Testbed.up`` returns once
#: every robot has a report from every other
SETTLE = 2.5
#: the paper's robot names, as testbed robots
NAMES = {r: r.lower() for r in ROBOTS}


def read_trace(path: Path) -> list[TraceEntry]:
    """A node's ``--trace`` file as simulator trace entries (torn last line skipped)."""
    out: list[TraceEntry] = []
    try:
        lines = Path(path).read_text().splitlines()
    except OSError:
        return out
    for line in lines:
        try:
            d = json.loads(line)
            out.append(TraceEntry(d["t"], d["robot"], d["what"], d["program_id"], d["other"], d["attempt"],
                                  d["detail"]))
        except (ValueError, KeyError):
            continue
    return out


def delivered_counts(trace: list[TraceEntry]) -> dict[str, int]:
    counts: dict[str, int] = {}
    for e in trace:
        if e.what == "delivered":
            counts[e.program_id] = counts.get(e.program_id, 0) + 1
    return counts


def hosts_at(trace: list[TraceEntry], t: float) -> dict[str, str]:
    """Program -> robot holding it at time ``t``, as the origin saw it."""
    where: dict[str, tuple[str, int]] = {}
    for e in trace:
        if e.t > t:
            break
        if e.what == "accepted":
            where[e.program_id] = (e.other, e.attempt)
        elif e.what == "failed" and where.get(e.program_id, ("", -1))[1] == e.attempt:
            del where[e.program_id]
        elif e.what == "delivered":
            where.pop(e.program_id, None)
    return {p: h for p, (h, _) in where.items()}


def _log_dir(tb: Testbed) -> Path:
    """The folder of a testbed's node logs and traces (``up`` makes it)."""
    if tb.log_dir is None:
        raise RuntimeError(f"testbed {tb.tb} is not up: it has no log folder")
    return tb.log_dir


def _keep(tb: Testbed, dest: Path) -> None:
    """Copy the testbed's node logs and traces before ``down`` deletes them."""
    import shutil

    dest.mkdir(parents=True, exist_ok=True)
    for f in _log_dir(tb).iterdir():
        shutil.copy(f, dest / f.name)


def identical_speed(robots: int, cores: int, quota: float | None = None) -> float:
    """The per-core speed of every robot, measured once here, before the nodes
    start: the true configuration the simulator runs at, and what every node
    is told with ``told_speed`` (an ablation; by default each node measures
    itself, as on a robot)."""
    import os

    from ramps.runtime.speed_probe import measure_speed

    q = quota if quota is not None else max(0.05, len(os.sched_getaffinity(0)) / robots)
    return round(measure_speed(0.5, quota=q, cores=cores), 4)


def _inject(tb, robot: str, kind: str) -> None:
    {"crash": tb.crash, "network": tb.cut, "cut": tb.cut, "freeze": tb.freeze}[kind](robot)


def run_plan(plan: FaultPlan, *, seed: int = 0, policy: str = "ramps", work: float | None = None,
             quota: float | None = None, lease_ms: int | None = None, finish_timeout: float = 1800.0,
             keep_logs: Path | None = None, discovery: str = "both", told_speed: bool = False,
             log: Callable[[str], None] | None = None) -> FaultRun:
    """One plan on a fresh five-robot testbed (see the module docstring); the nodes measure
    their own speeds (``told_speed``: each is handed the one measured here, an ablation)."""
    from ramps.testbed import Testbed

    log = log or (lambda _m: None)
    events = sorted([(at, 0, "fail", robot, kind) for at, robot, kind in plan.failures] +
                    [(at, 1, "snap", label, "") for label, at in plan.snapshots])
    gap = (plan.failures[1][0] - plan.failures[0][0]) if len({f[0] for f in plan.failures}) > 1 else \
        (plan.snapshots[-1][1] + 1.0 - plan.failures[0][0])
    units = float(work if work is not None else 0.9 * gap)
    expected = burn(units=units)["checksum"] if units <= 2 else None
    speed = identical_speed(len(NAMES), 4, quota)
    with Testbed(list(NAMES.values()), cores=4, quota=quota, speed=speed if told_speed else None, policy=policy,
                 lease_ms=lease_ms,
                 discovery=discovery) as tb, \
            tb.client("r1", timeout=30.0) as team:
        log(f"{plan.name}: testbed {tb.tb} up, submitting 15 x burn({units:g} units) from r1")
        t0 = time.monotonic()
        opts = team.options(work=units)
        futures = [opts.submit("burn", units=units) for _ in range(15)]
        fail_at: dict[str, float] = {}
        snap_at: dict[str, float] = {}
        for at, _, what, name, kind in events:
            time.sleep(max(0.0, t0 + at - time.monotonic()))
            if what == "fail":
                robot = NAMES[name]
                fail_at[name] = time.monotonic()
                _inject(tb, robot, kind)
                log(f"  t={time.monotonic() - t0:5.1f} s  {kind} of {name}")
            else:
                snap_at[name] = time.monotonic()
        done, pending = wait_futures(futures, timeout=finish_timeout)
        completed = 0
        for f in done:
            if f.exception() is None:
                res = f.result()
                if res.get("iterations") == round(units * 16_000_000) and (expected is None or
                                                                          res.get("checksum") == expected):
                    completed += 1
        for f in pending:
            f.cancel()
        makespan = time.monotonic() - t0
        time.sleep(0.2)  # the origin's last trace lines
        trace = sorted(read_trace(_log_dir(tb) / "r1.trace.jsonl"), key=lambda e: e.t)
        if keep_logs is not None:
            _keep(tb, Path(keep_logs) / f"{plan.name.replace(' ', '_').replace(':', '').replace(',', '-')}-{seed}")
    dup = sum(n - 1 for n in delivered_counts(trace).values() if n > 1)
    dists: dict[str, dict[str, int]] = {}
    for label, at in snap_at.items():
        held = list(hosts_at(trace, at).values())
        dists[label] = {r: held.count(NAMES[r]) for r in ROBOTS if not (r in fail_at and fail_at[r] <= at)}
        log(f"  {label}: {dists[label]}")
    records = []
    for at, name, kind in plan.failures:
        t_fail = fail_at[name]
        done_before = {e.program_id for e in trace if e.what == "delivered" and e.t < t_fail}
        rec = _failure_record(trace, t_fail, NAMES[name], kind, done_before)
        records.append(msgspec.structs.replace(rec, robot=name, at=at))
    log(f"  {completed}/15 completed in {makespan:.1f} s, duplicated {dup}")
    return FaultRun(plan=plan.name, seed=seed, distributions=dists,
                    classifications={k: classify_counts(list(v.values())) for k, v in dists.items()},
                    failures=records, completed=completed, lost=15 - completed, duplicated=dup, makespan=makespan)
