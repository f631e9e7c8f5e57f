"""``ramps bench first-calls``: how fast a fresh team runs a heavy program's first calls.

How this works: a fresh team of ``nodes`` real ``ramps node`` processes on
loopback (``cores`` each, as ``ramps bench dispatch``), one client, every
node writing its trace (``--trace``). The program (``route_plan`` by
default: OR-Tools' CP-SAT, whose import costs about a CPU-second) is called
``calls`` times with different seeds, in three phases on the same team,
each call timed from ``submit`` to its result:

    cold, at once:          the team's first calls, all submitted together
    warm, one after another the same calls, each after the last one's result
    warm, at once           the same calls, all submitted together again

The figures that matter are the cold burst's median over the one-after-another
median, and over the warm burst's (the same calls at once, on workers that
have run them): the executor's fork server imports every program's module,
and the modules a program declares in ``preload``, before it forks a worker,
so a fresh team's first calls pay no import, and a cold burst is no slower
than a warm one; what is left of the first ratio is the calls sharing the
cores.

Where a call's time goes (``stages``, from the nodes' traces; ``t`` there is
the host's monotonic clock, the same as this process's): submit to placed
(the client's ``submit``, itself ``submit_call_ms``: the argument check and
the message; the origin's placement), placed to started (the offer
to the host, which hands it to its executor), started to finished (waiting
for a worker and running: this is where calls share the cores) and finished
to the result in the client (the result's way back). The CPU of a call: the
program's own figure where its result has one (``route_plan``'s
``cpu_seconds``, its solve, measured in the worker), and every worker's CPU
time over the phase divided by its calls (the whole call, as the workers
report it to their node); the workers forked during a phase are counted.

The bound (``bound``): ``calls`` calls of ``c`` seconds each, on the
``host_cores`` this process may run on; ``c`` is a call's CPU (the workers'
figure one after another), or, where it is longer, the time a call alone
took from started to finished (on a loaded host a call alone gets less than
a core: its CPU took that long at this moment's share). One after another a
call takes ``seq`` (``c`` and what ramps adds). At once, however they are scheduled, the
calls finish in ``calls * c / host_cores`` at the earliest; their median
finishes at ``m * c`` at the earliest, ``m`` the median of ``ceil(i /
host_cores)`` over the calls (two at a time on 2 cores: c, c, 2c, 2c, 3c, 3c,
so ``m`` = 2), or at ``calls / host_cores * c`` when every call runs at once
and they share the cores (processor sharing: 3c). So the ratio of the
medians is at least ``1 + (m - 1) * c / seq``: about 2x for six calls on two
cores, 3x shared (a little less: what ramps adds to a call counts on both
sides; a host with a core per robot, three, allows 1.5x and 2x), and 1x
needs a core per call. Other processes on the host (its load average, taken at
each phase) lower the cores left: ``cores_used`` is the CPU the workers got
over a phase's wall time (on a loaded host, six calls at once may get no
more of it than one call alone).

``--testbed`` (``ramps.bench.firstcalls_testbed``) runs the same phases, with
the same stages and CPU figures, on a fresh emulated team a round: robots
of their own cores, whose bound the emulated team sets, not this host.

Memory: the resident (RSS), proportional (PSS: shared pages divided among
their users) and unique (USS) memory of each node's fork server and its idle
workers, right after the team started and again after the calls (once the
extra workers retired). Rounds repeat everything on a fresh team. Figures
are printed and saved as JSON; nothing here asserts a target.
"""

from __future__ import annotations

import json
import math
import os
import statistics
import sys
import threading
import time
from collections import Counter
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, Protocol

import psutil

from ramps.bench.simulator import machine
from ramps.runtime.workers import RETIRE_AFTER
from ramps.testing import LocalTeam

MB = 1 << 20
#: the trace lines that time a call, in the order a call meets them (a program
#: its origin runs itself has no ``started`` and ``finished`` lines: its
#: ``accepted`` and ``delivered`` stand for them)
STAGE_LINES = ("placed", "started", "accepted", "finished", "delivered")


class HasNodes(Protocol):
    """A started team as the measuring reads it: each robot's node process, by robot
    (``LocalTeam.nodes``; ``EmulatedTeam`` on the testbed), whose ``pid`` is the node's."""

    @property
    def nodes(self) -> Mapping[str, Any]: ...


class _TracedTeam(LocalTeam):
    """A ``LocalTeam`` whose every node writes its trace to ``<log dir>/<robot>.trace``."""

    def node_argv(self, name: str, port: int, cores: int | None, policy: str | None) -> list[str]:
        return super().node_argv(name, port, cores, policy) + ["--trace", str(self.log_dir / f"{name}.trace")]


def _call(fut: Any, t0: float, sent: float, t1: float) -> dict:
    value = fut.result(timeout=1)  # a failed call fails the benchmark
    cpu = value.get("cpu_seconds") if isinstance(value, dict) else None
    return {"submit": t0, "sent": sent, "result": t1, "host": fut.host,
            "program_cpu_s": cpu if isinstance(cpu, (int, float)) else None}


def _at_once(client: Any, program: str, calls: int, kwargs: dict) -> list[dict]:
    """Submit ``calls`` programs together; each one's submit, sent (``submit``
    returned) and result times (monotonic)."""
    stamps: list[tuple[float, float, float]] = [(0.0, 0.0, 0.0)] * calls
    done = threading.Semaphore(0)
    futs = []
    for i in range(calls):
        t0 = time.monotonic()
        fut = client.submit(program, seed=i, **kwargs)
        sent = time.monotonic()

        def finished(f: Any, i: int = i, t0: float = t0, sent: float = sent) -> None:
            stamps[i] = (t0, sent, time.monotonic())
            done.release()

        fut.add_done_callback(finished)
        futs.append(fut)
    for _ in range(calls):
        done.acquire(timeout=300)
    return [_call(fut, *stamps[i]) for i, fut in enumerate(futs)]


def _one_after_another(client: Any, program: str, calls: int, kwargs: dict) -> list[dict]:
    out = []
    for i in range(calls):
        t0 = time.monotonic()
        fut = client.submit(program, seed=i, **kwargs)
        sent = time.monotonic()
        fut.result(timeout=300)
        out.append(_call(fut, t0, sent, time.monotonic()))
    return out


def _mem(proc: psutil.Process) -> dict:
    m = proc.memory_full_info()
    return {"rss_mb": m.rss / MB, "pss_mb": getattr(m, "pss", 0) / MB, "uss_mb": m.uss / MB}


def _fork_servers(team: HasNodes) -> dict[str, psutil.Process]:
    servers = {}
    for name, node in team.nodes.items():
        try:
            for child in psutil.Process(node.pid).children():
                if "--fork-server" in child.cmdline():
                    servers[name] = child
        except psutil.Error:
            continue
    return servers


def worker_cpu(team: HasNodes) -> dict[int, float]:
    """CPU seconds (user and system) of every live worker of every node, by pid."""
    cpu = {}
    for server in _fork_servers(team).values():
        try:
            workers = server.children()
        except psutil.Error:
            continue
        for w in workers:
            try:
                t = w.cpu_times()
            except psutil.Error:
                continue
            cpu[w.pid] = t.user + t.system
    return cpu


def executor_memory(team: HasNodes) -> dict:
    """Each robot's node, fork server and workers: RSS, PSS and USS in MB
    (and the fork server's CPU seconds so far: its start, preload included)."""
    robots = {}
    servers = _fork_servers(team)
    for name, node in team.nodes.items():
        entry: dict = {"node": _mem(psutil.Process(node.pid)), "fork_server": None, "workers": []}
        child = servers.get(name)
        if child is not None:
            try:
                entry["fork_server"] = _mem(child)
                cpu = child.cpu_times()
                entry["fork_server"]["cpu_s"] = cpu.user + cpu.system
                entry["workers"] = [_mem(w) for w in child.children()]
            except psutil.Error:
                pass
        ws = entry["workers"]
        entry["executor_pss_mb"] = ((entry["fork_server"] or {}).get("pss_mb", 0.0)
                                    + sum(w["pss_mb"] for w in ws))
        robots[name] = entry
    return robots


def read_traces(paths: list[Path]) -> dict[str, dict[str, float]]:
    """program id -> {trace line kind: its earliest ``t``} over the traces at ``paths``."""
    seen: dict[str, dict[str, float]] = {}
    for path in paths:
        try:
            lines = path.read_text().splitlines()
        except OSError:
            continue
        for line in lines:
            try:
                rec = json.loads(line)
                pid, what, t = rec["program_id"], rec["what"], float(rec["t"])
            except (ValueError, KeyError, TypeError):
                continue
            if what in STAGE_LINES:
                kinds = seen.setdefault(pid, {})
                kinds[what] = min(t, kinds.get(what, t))
    return seen


def _submission_order(pid: str) -> tuple[str, int]:
    head, _, seq = pid.rpartition("-")  # "r1#93702-12": an origin's programs are numbered as they come
    return (head, int(seq)) if seq.isdigit() else (pid, 0)


def stages(calls: list[dict], traced: dict[str, dict[str, float]]) -> list[dict] | None:
    """Each call's stages in ms (see the module's docstring), the calls in
    submission order matched to the traced programs in the origin's order;
    None when the traces do not hold one program per call."""
    pids = sorted((p for p, kinds in traced.items() if "placed" in kinds), key=_submission_order)
    if len(pids) != len(calls):
        return None
    out = []
    for call, pid in zip(calls, pids):
        k = traced[pid]
        started, finished = k.get("started", k.get("accepted")), k.get("finished", k.get("delivered"))
        if started is None or finished is None:
            return None
        out.append({"program_id": pid, "submit_to_placed_ms": (k["placed"] - call["submit"]) * 1e3,
                    "submit_call_ms": (call.get("sent", call["submit"]) - call["submit"]) * 1e3,
                    "placed_to_started_ms": (started - k["placed"]) * 1e3,
                    "started_to_finished_ms": (finished - started) * 1e3,
                    "finished_to_result_ms": (call["result"] - finished) * 1e3})
    return out


def median_slot(calls: int, cores: int) -> float:
    """The median, over ``calls`` equal calls run ``cores`` at a time, of
    the number of calls' CPU each has waited for when it ends (its own
    included): 6 calls on 2 cores end after 1, 1, 2, 2, 3, 3, median 2."""
    return statistics.median(math.ceil(i / cores) for i in range(1, calls + 1))


def bound(calls: int, host_cores: int, cpu_s: float, seq_p50_ms: float, run_alone_ms: float | None = None) -> dict:
    """The least ratio of the at-once median over the one-after-another
    median that ``host_cores`` allow for ``calls`` calls of ``cpu_s`` each
    (or of ``run_alone_ms`` each where that is longer: a loaded host), one
    after another ``seq_p50_ms`` each (the module's docstring)."""
    c_ms = min(seq_p50_ms, max(cpu_s * 1e3, run_alone_ms or 0.0))
    m = median_slot(calls, host_cores)
    shared = max(1.0, calls / host_cores)
    return {"host_cores": host_cores, "cpu_ms": cpu_s * 1e3, "run_alone_ms": run_alone_ms, "c_ms": c_ms,
            "median_slot": m, "shared_slot": shared,
            "p50_floor_ms": seq_p50_ms + (m - 1) * c_ms, "ratio_floor": 1 + (m - 1) * c_ms / seq_p50_ms,
            "shared_p50_floor_ms": seq_p50_ms + (shared - 1) * c_ms,
            "shared_ratio_floor": 1 + (shared - 1) * c_ms / seq_p50_ms,
            "cores_for_1x": calls}


def _phase(team: HasNodes, run: Any) -> dict:
    load = os.getloadavg()[0]
    before = worker_cpu(team)
    calls = run()
    after = worker_cpu(team)
    lat = [(c["result"] - c["submit"]) for c in calls]
    s = sorted(lat)
    prog_cpu = [c["program_cpu_s"] for c in calls if c["program_cpu_s"] is not None]
    used = sum(cpu - before.get(pid, 0.0) for pid, cpu in after.items())
    wall = max(c["result"] for c in calls) - min(c["submit"] for c in calls)
    return {"cores_used": used / wall if wall > 0 else 0.0, "ms": [x * 1e3 for x in lat], "p50_ms": statistics.median(s) * 1e3, "max_ms": s[-1] * 1e3,
            "min_ms": s[0] * 1e3, "hosts": [c["host"] for c in calls], "calls": calls,
            "program_cpu_ms": [x * 1e3 for x in prog_cpu],
            "program_cpu_p50_ms": statistics.median(prog_cpu) * 1e3 if prog_cpu else None,
            "worker_cpu_per_call_ms": used / len(calls) * 1e3,
            "workers_forked": len(set(after) - set(before)), "loadavg_1m": load}


def _stage_p50(phase: dict) -> dict | None:
    st = phase.get("stages")
    if not st:
        return None
    return {k: statistics.median(s[k] for s in st) for k in st[0] if k.endswith("_ms")}


def measure(team: HasNodes, client: Any, calls: int, program: str, kwargs: dict,
            traces: Callable[[], list[Path]]) -> dict:
    """The three phases on a started ``team`` through ``client``, each call's stages from the
    ``traces`` it writes, and the executors' memory before and after: what a round on loopback
    and one on the testbed (``ramps.bench.firstcalls_testbed``) share."""
    mem_start = executor_memory(team)
    cold = _phase(team, lambda: _at_once(client, program, calls, kwargs))
    seq = _phase(team, lambda: _one_after_another(client, program, calls, kwargs))
    warm = _phase(team, lambda: _at_once(client, program, calls, kwargs))
    traced = read_traces(traces())
    done = cold["calls"] + seq["calls"] + warm["calls"]
    st = stages(done, traced)
    for i, phase in enumerate((cold, seq, warm)):
        phase["stages"] = st[i * calls:(i + 1) * calls] if st else None
        phase["stages_p50_ms"] = _stage_p50(phase)
    time.sleep(RETIRE_AFTER + 1.5)  # workers beyond the cores retire
    return {"cold_at_once": cold, "warm_one_after_another": seq, "warm_at_once": warm,
            "memory_start": mem_start, "memory_after": executor_memory(team)}


def run_alone_ms(m: dict) -> float | None:
    """The p50 time a call alone took from started to finished (one after another), if traced."""
    return (m["warm_one_after_another"]["stages_p50_ms"] or {}).get("started_to_finished_ms")


def round_result(started_s: float, m: dict, b: dict) -> dict:
    """A round's figures: ``measure``'s, the ratios and the bound ``b``."""
    cold, seq, warm = m["cold_at_once"], m["warm_one_after_another"], m["warm_at_once"]
    return {"team_start_s": started_s, "cold_at_once": cold, "warm_one_after_another": seq, "warm_at_once": warm,
            "cold_over_sequential_p50": cold["p50_ms"] / seq["p50_ms"],
            "cold_over_warm_at_once_p50": cold["p50_ms"] / warm["p50_ms"], "bound": b,
            "loadavg_1m": [cold["loadavg_1m"], seq["loadavg_1m"], warm["loadavg_1m"], os.getloadavg()[0]],
            "memory_start": m["memory_start"], "memory_after": m["memory_after"]}


def _round(nodes: int, cores: int, calls: int, program: str, kwargs: dict, host_cores: int) -> dict:
    t0 = time.perf_counter()
    # route_plan's OR-Tools in the fork server before the first call: what this bench measures
    with _TracedTeam(nodes, cores=cores, speed=1.0, env=dict(os.environ, RAMPS_PRELOAD_BUNDLED="1")) as team:
        started_s = time.perf_counter() - t0
        client = team.client()
        time.sleep(1.5)  # let every load server hear every robot once
        m = measure(team, client, calls, program, kwargs, lambda: sorted(team.log_dir.glob("*.trace")))
    seq = m["warm_one_after_another"]
    b = bound(calls, host_cores, seq["worker_cpu_per_call_ms"] / 1e3, seq["p50_ms"], run_alone_ms(m))
    return round_result(started_s, m, b)


def _bound_head(b: dict, calls: int) -> str:
    if b.get("mode") == "testbed":  # ramps.bench.firstcalls_testbed.emulated_bound
        return (f"the emulated team's bound for {calls} calls of {b['c_ms']:.0f} ms ({b['host_cpu_ms']:.0f} ms of host "
                f"CPU, {b['cpu_ms']:.0f} ms on an emulated core of {b['core_host_cores']:.2f} host cores) on "
                f"{b['robots']} robots of {b['cores_per_robot']} cores")
    return f"this host's bound for {calls} calls of {b['c_ms']:.0f} ms ({b['cpu_ms']:.0f} ms CPU) on {b['host_cores']} cores"


def describe_round(i: int, r: dict) -> str:
    """One round's ratio beside the bound this host (or the emulated team) sets, and where the time went."""
    b, seq, cold = r["bound"], r["warm_one_after_another"], r["cold_at_once"]
    hb = b.get("host")  # the testbed's: the host's cores within a CFS period
    text = (f"round {i}: cold at once / one after another {r['cold_over_sequential_p50']:.1f}x; "
            f"{_bound_head(b, len(cold['ms']))}: at least "
            f"{b['ratio_floor']:.1f}x ({b['median_slot']:g} calls' CPU before the median ends), "
            f"{b['shared_ratio_floor']:.1f}x if all share the cores; 1x needs {b['cores_for_1x']} cores; "
            + (f"within a CFS period the robots share this host's {hb['host_cores']} cores: at least "
               f"{hb['ratio_floor']:.1f}x, {hb['shared_ratio_floor']:.1f}x shared; " if hb else "")
            + f"load average {min(r['loadavg_1m']):.1f}-{max(r['loadavg_1m']):.1f}; the workers had "
            f"{cold['cores_used']:.2f} cores in the cold burst, {seq['cores_used']:.2f} one after another. CPU per call "
            f"(workers) cold {cold['worker_cpu_per_call_ms']:.0f} ms, one after another "
            f"{seq['worker_cpu_per_call_ms']:.0f} ms; workers forked in the cold burst {cold['workers_forked']}; "
            f"the cold burst ran on " + ", ".join(f"{h} {n}" for h, n in sorted(Counter(cold["hosts"]).items())))
    for label, phase in (("cold at once", cold), ("one after another", seq)):
        p = phase["stages_p50_ms"]
        if p:
            text += (f"; {label} p50: submit to placed {p['submit_to_placed_ms']:.1f} ms (in the client's "
                     f"submit {p['submit_call_ms']:.1f}), to started "
                     f"{p['placed_to_started_ms']:.1f}, to finished {p['started_to_finished_ms']:.1f}, to the "
                     f"result {p['finished_to_result_ms']:.1f}")
    return text


def host_cores() -> int:
    """The cores this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def run_rounds(rounds: int, one: Callable[[], dict], show: Any = None) -> list[dict]:
    """``rounds`` results of ``one``, each shown as it ends (``describe_round``; default: to stderr)."""
    results = []
    for i in range(1, rounds + 1):
        results.append(one())
        (show or (lambda s: print(s, file=sys.stderr, flush=True)))(describe_round(i, results[-1]))
    return results


def summary(results: list[dict], **head: Any) -> dict:
    """The benchmark's JSON: ``head`` (what ran, and where), the rounds and their spread."""
    def spread(key: str) -> dict:
        xs = [r[key] for r in results]
        return {"median": statistics.median(xs), "min": min(xs), "max": max(xs)}

    return {"benchmark": "first-calls", "machine": machine(), **head, "rounds": results,
            "cold_over_sequential_p50": spread("cold_over_sequential_p50"),
            "cold_over_warm_at_once_p50": spread("cold_over_warm_at_once_p50"),
            "ratio_floor": {"median": statistics.median(r["bound"]["ratio_floor"] for r in results),
                            "shared": statistics.median(r["bound"]["shared_ratio_floor"] for r in results)}}


def program_kwargs(program: str, picks: int) -> dict:
    return {"picks": picks} if program == "route_plan" else {}


def bench_first_calls(*, nodes: int = 3, cores: int = 2, calls: int = 6, rounds: int = 1,
                      program: str = "route_plan", picks: int = 8, show: Any = None) -> dict:
    """On loopback (``mode`` "loopback"). ``program`` takes ``seed`` (call i gets seed i) and, for
    route_plan, ``picks``. ``show`` gets each round's line beside its bound (``run_rounds``)."""
    kwargs = program_kwargs(program, picks)
    hc = host_cores()
    results = run_rounds(rounds, lambda: _round(nodes, cores, calls, program, kwargs, hc), show)
    return summary(results, mode="loopback", nodes=nodes, cores=cores, calls=calls, program=program, kwargs=kwargs,
                   host_cores=hc)
