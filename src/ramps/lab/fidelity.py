"""How closely a testbed robot follows the processor-sharing model.

How this works: one robot of ``cores`` emulated cores (``quota`` host cores)
runs ``k`` identical programs of ``work`` units at once next to ``b`` busy
background processes. Weighted processor sharing (the simulator, the cost
model, ramps.core.cost.program_share) says every program finishes after::

    work / (speed * cost.program_share(cores, k, b, weight))

where ``speed`` is one emulated core's units per second, measured once, and
``weight`` that of the node's workers at nice 10 against the load at nice 0
(at equal weights this is ``work / speed * max(1, (k + b) / cores)``). Each
case submits the ``k`` programs from the robot itself (a team of one, so
they run there) and times every result. It also reads the CPU the robot's
cgroup used meanwhile: the model gives it ``core * min(k + b, cores)`` host
cores (``core = quota / cores``). With per-program caps
(``ramps.testbed.caps``) a lone program runs at one emulated core; without
them it runs on the whole robot, up to ``cores`` times faster than the model.

The CPU figure checks the emulation; completion times also carry the host's
own noise: a work unit's CPU cost on this 2-core VM moves by 10-40% from
minute to minute (``unit_cpu_s`` before and after). So each case also reads
the CPU seconds its programs' worker processes used, gives the unit cost
during the case (``unit_cpu``), and compares the completion times with the
model scaled by it (``corrected_error``): what is left is the emulation's.

Run ``ramps testbed fidelity`` (root); ``--json`` for the figures.
"""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import msgspec

from ramps.core.cost import nice_weight, program_cores, program_share
from ramps.runtime.measure import cgroup_usage, proc_cpu, proc_stat_fields
from ramps.runtime.settings import NodeSettings

if TYPE_CHECKING:
    from ramps.testbed import Testbed

CASES = [(1, 0), (2, 0), (4, 0), (6, 0), (8, 0), (1, 2), (4, 2), (6, 2)]


class FidelityCase(msgspec.Struct, kw_only=True):
    programs: int
    busy: int
    model: float
    mean: float
    first: float
    last: float
    error: float  # (mean - model) / model
    #: host cores the robot used while the programs ran, and the model's
    cpu: float
    cpu_model: float
    #: CPU seconds per work unit in the programs' workers during the case, and
    #: the error against the model scaled by it over the calibration's
    unit_cpu: float
    corrected_error: float
    #: CPU seconds the robot's cgroup used during the case, by whom: the
    #: programs' workers, the busy load, and the rest (the node process, its
    #: worker fork server, the shells around them): ``overhead_cpu_s``
    robot_cpu_s: float = 0.0
    program_cpu_s: float = 0.0
    load_cpu_s: float = 0.0
    overhead_cpu_s: float = 0.0
    #: the overhead split by process kind (node, fork_server, other)
    overhead_by: dict[str, float] = {}
    #: the last program's completion (the makespan) against the model scaled by ``unit_cpu``
    corrected_last_error: float = 0.0
    #: the cores the robot's node said it used itself (``LoadReport.node_cpu``, at the case's
    #: end), the cost model's time with them taken off the robot's cores, and the last
    #: program against that, scaled by ``unit_cpu`` like ``corrected_last_error``
    node_cores: float = 0.0
    cost_model: float = 0.0
    cost_model_last_error: float = 0.0


class FidelityReport(msgspec.Struct, kw_only=True):
    caps: bool
    cores: int
    quota: float
    speed: float
    work: float
    cases: list[FidelityCase]
    #: mean of |error| over the cases, of completion times and of the CPU used
    mean_abs_error: float
    mean_abs_cpu_error: float
    mean_abs_corrected_error: float
    #: host speed drift: a burn unit's CPU seconds at the start and the end
    unit_cpu_s: tuple[float, float]


def model_time(work: float, speed: float, cores: float, programs: int, busy: int, weight: float = 1.0) -> float:
    return work / (speed * program_share(cores, programs, busy, weight))


def _unit_cpu() -> float:
    from ramps.programs.burn import burn

    t = time.process_time()
    burn(units=0.3)
    return round((time.process_time() - t) / 0.3, 3)


def run_fidelity(*, caps: bool = True, cores: int = 4, quota: float = 0.8, work: float = 2.0,
                 cases: list[tuple[int, int]] | None = None, told_speed: bool = False,
                 log: Callable[[str], None] | None = None) -> FidelityReport:
    from ramps.testbed import Testbed
    from ramps.lab.experiments import SETTLE, identical_speed

    log = log or (lambda _m: None)
    weight = nice_weight(NodeSettings().worker_nice)  # the testbed's nodes run with the default
    unit0 = _unit_cpu()
    speed = identical_speed(1, cores, quota)
    out: list[FidelityCase] = []
    with Testbed(["r1"], cores=cores, quota=quota, speed=speed if told_speed else None, caps=caps) as tb, \
            tb.client("r1", timeout=30.0) as team:
        time.sleep(SETTLE)
        for k, b in cases or CASES:
            tb.add_load("r1", b)
            time.sleep(1.5 if b else 0.2)  # the load is adopted, capped and seen by the node
            out.append(_measure_case(tb, team, k, b, work=work, speed=speed, cores=cores, quota=quota,
                                     weight=weight, log=log))
            if b:
                tb.remove_load("r1")
    unit1 = _unit_cpu()
    return FidelityReport(caps=caps, cores=cores, quota=quota, speed=speed, work=work, cases=out,
                          mean_abs_error=round(statistics.fmean(abs(c.error) for c in out), 3),
                          mean_abs_cpu_error=round(statistics.fmean(abs(c.cpu - c.cpu_model) / c.cpu_model
                                                                    for c in out), 3),
                          mean_abs_corrected_error=round(statistics.fmean(abs(c.corrected_error) for c in out), 3),
                          unit_cpu_s=(unit0, unit1))


def _measure_case(tb: Testbed, team: Any, k: int, b: int, *, work: float, speed: float, cores: int, quota: float,
                  weight: float, log: Callable[[str], None]) -> FidelityCase:
    """One case on robot r1, its ``b`` busy processes already running: ``k`` programs of
    ``work`` units at once, their times and the robot's CPU beside the model's."""
    from ramps.lab.experiments import wait_futures

    dirs = [Path(d) for d in tb.robots["r1"]["cgroup"]]
    cpu_dir, acct_dir = dirs[0], (dirs[1] if len(dirs) > 1 else None)
    before = robot_cpu(tb)
    t0, u0 = time.monotonic(), cgroup_usage(cpu_dir, acct_dir)
    futures = [team.options(work=work).submit("burn", units=work) for _ in range(k)]
    took: list[float] = []
    for f in futures:
        f.add_done_callback(lambda _f, took=took, t0=t0: took.append(time.monotonic() - t0))
    seen = dict(before)  # workers come and go (extra ones exit 2 s after they fall idle): sample
    deadline = time.monotonic() + 600.0
    while not all(f.done() for f in futures) and time.monotonic() < deadline:
        merge_cpu(seen, robot_cpu(tb))
        time.sleep(0.1)
    done, pending = wait_futures(futures, timeout=1.0)
    used = cgroup_usage(cpu_dir, acct_dir) - u0
    node_cores = next((r.node_cpu for r in team.status().robots if r.robot == "r1"), 0.0)
    cpu = used / max(time.monotonic() - t0, 1e-3)
    merge_cpu(seen, robot_cpu(tb))
    by: dict[str, float] = {}
    for p, (kind, secs) in seen.items():
        by[kind] = by.get(kind, 0.0) + secs - before.get(p, (kind, 0.0))[1]
    spent = by.get("worker", 0.0)
    unit = spent / (k * work)
    bad = [f for f in done if f.exception() is not None]
    if pending or bad:
        raise RuntimeError(f"case {k} programs + {b} busy: {len(pending)} unfinished, "
                           f"{len(bad)} failed ({bad[0].exception() if bad else ''})")
    time.sleep(0.05)
    m = model_time(work, speed, cores, k, b, weight)
    mean = statistics.fmean(took)
    cpu_m = quota / cores * min(k + b, cores)
    calib = quota / (cores * speed)  # CPU seconds of a unit when the speed was measured
    mc = m * unit / calib
    # the cost model's own time: the cores the node reports using itself taken off (LoadView.scan)
    cm = model_time(work, speed, program_cores(cores, node_cores), k, b, weight)
    case = FidelityCase(programs=k, busy=b, model=round(m, 2), mean=round(mean, 2), first=round(min(took), 2),
                        last=round(max(took), 2), error=round((mean - m) / m, 3), cpu=round(cpu, 3),
                        cpu_model=round(cpu_m, 3), unit_cpu=round(unit, 3),
                        corrected_error=round((mean - mc) / mc, 3),
                        corrected_last_error=round((max(took) - mc) / mc, 3), robot_cpu_s=round(used, 2),
                        program_cpu_s=round(spent, 2), load_cpu_s=round(by.get("load", 0.0), 2),
                        overhead_cpu_s=round(used - spent - by.get("load", 0.0), 2),
                        overhead_by={kk: round(v, 2) for kk, v in sorted(by.items())
                                     if kk not in ("worker", "load")},
                        node_cores=round(node_cores, 3), cost_model=round(cm, 2),
                        cost_model_last_error=round((max(took) - cm * unit / calib) / (cm * unit / calib), 3))
    log(f"  {k} programs + {b} busy: model {m:.1f} s, measured {mean:.1f} s "
        f"({min(took):.1f}-{max(took):.1f}), error {case.error:+.0%}; "
        f"robot CPU {cpu:.2f} host cores, model {cpu_m:.2f}; a unit cost {unit:.2f} CPU s "
        f"(calibration {calib:.2f}), corrected error {case.corrected_error:+.0%} "
        f"(last {case.corrected_last_error:+.0%}); robot {used:.1f} CPU s, "
        f"programs {spent:.1f}, outside them {case.overhead_cpu_s:.1f} {case.overhead_by}; the node "
        f"reported using {node_cores:.2f} cores itself, so the cost model says {cm:.1f} s: last "
        f"{case.cost_model_last_error:+.0%} of it, corrected")
    return case


def _kind(pid: int, argv: bytes, load: set[int]) -> str:
    """What a process of a robot's cgroup is: ``worker`` (runs programs),
    ``fork_server`` (forks workers), ``node``, ``load`` or ``other``."""
    if pid in load:
        return "load"
    if b"--fork-server" in argv:  # the server and the workers it forks share its argv: tell them by the parent
        f = proc_stat_fields(pid)
        try:
            parent = Path(f"/proc/{f[1]}/cmdline").read_bytes() if f else b""
        except OSError:
            parent = b""
        return "worker" if b"--fork-server" in parent else "fork_server"
    if b"ramps.runtime.worker" in argv:
        return "worker"
    if b"ramps.cli" in argv and b"node" in argv:
        return "node"
    return "other"


def merge_cpu(seen: dict[int, tuple[str, float]], new: dict[int, tuple[str, float]]) -> None:
    """``seen.update(new)``, but a process keeps the kind it was first given:
    a worker that is exiting (a zombie) has an empty command line."""
    for pid, (kind, secs) in new.items():
        seen[pid] = (seen[pid][0] if pid in seen else kind, secs)


def robot_cpu(tb, robot: str = "r1") -> dict[int, tuple[str, float]]:
    """CPU seconds so far (utime + stime) of every process in the robot's
    cgroup tree, with its kind (``_kind``)."""
    from ramps.testbed.procs import _cgroup_pids

    rb = tb.robots[robot]
    load = {p for p, _ in rb["load_pids"]}
    out = {}
    for pid in _cgroup_pids(rb["cgroup"][:1]):
        try:
            cmd = Path(f"/proc/{pid}/cmdline").read_bytes()
        except OSError:
            continue
        got = proc_cpu(pid)
        if got is None:
            continue
        out[pid] = (_kind(pid, cmd, load), got[0])
    return out
