"""Nodes restarted under load, on the testbed: an origin's node killed with
programs in flight and started again by a supervisor (``ramps testbed
experiment origin-restart``), and every node restarted one by one while
applications submit (``rolling-restart``, ``run_rolling_restart``).

How this works: a fresh testbed of ``robots`` robots (2 cores each at the
default quota, nodes measuring themselves); a client in the root namespace
submits ``programs`` ``burn`` programs to r1's node, waits until they run
across the team, then SIGKILLs r1's node alone (``stress.crash_node``: what
a supervisor restarts), optionally cuts r1's link too, and after ``down``
seconds (the link: ``cut`` seconds) starts the node again with the same
command, so it opens the same durable record. The client waits through it
(``origin_grace``). Measured: programs delivered with the right result,
how many were delivered more than once (the restarted origin's trace:
``delivered`` lines per program), how many finished on the host that held
them before the crash without that host stopping them (kept: attempt 1
there, no ``origin_gone`` in the host's trace), how many their hosts
stopped or whose results they dropped because the origin was away longer
than ``origin_hold`` (offered again by the restarted origin, they ran
again on the same host as the same attempt), how many were placed again
elsewhere, and the seconds from the crash to the last outcome.
"""

from __future__ import annotations

import time
from collections import Counter
from typing import Callable

import msgspec

from ramps.runtime.spin import ITERATIONS_PER_UNIT
from ramps.testbed import stress as stresses

#: seconds between the testbed being up and the first submit (every robot's load report heard)
SETTLE = 2.5


class RestartRun(msgspec.Struct, kw_only=True):
    down: float
    cut: float
    programs: int
    delivered: int
    wrong: int
    lost: int
    duplicated: int
    #: programs whose host before the crash delivered them, having kept them through it
    kept: int
    #: programs their hosts stopped, or whose results they dropped, while the origin was away
    #: longer than ``origin_hold`` (the restarted origin offered them again)
    dropped: int
    #: programs placed again after the restart (their copy died with the node, or the hosts gave up)
    again: int
    #: where the programs ran when the node was killed: robot -> count
    before: dict[str, int]
    resumed: int
    seconds_to_last: float
    error: str = ""


def run_origin_restart(down: float, *, cut: float = 0.0, programs: int = 15, robots: int = 5, units: float = 1.5,
                       origin_hold: float | None = None, log: Callable[[str], None] | None = None) -> RestartRun:
    from ramps.testbed import Testbed
    from ramps.lab.experiments import read_trace

    log = log or (lambda _m: None)
    names = [f"r{i}" for i in range(1, robots + 1)]
    expected = round(units * ITERATIONS_PER_UNIT)
    config = {"core": {"origin_hold": origin_hold}} if origin_hold is not None else None
    with Testbed(names, cores=2, config=config) as tb, \
            tb.client("r1", timeout=30.0, origin_grace=max(down, cut) + 120.0) as team:
        futs = [team.options(work=units).submit("burn", units=units) for _ in range(programs)]
        deadline = time.monotonic() + 30.0
        while any(f.state not in ("running", "progress") for f in futs) and time.monotonic() < deadline:
            time.sleep(0.1)
        before = Counter(f.host for f in futs)
        t0 = time.monotonic()
        stresses.crash_node(tb, "r1", settle=0.2)
        if cut:
            tb.cut("r1")
        log(f"  node of r1 killed with {programs} programs in flight ({dict(sorted(before.items()))})"
            + (f", its link cut for {cut:g} s" if cut else "") + f"; restarted {max(down, cut):g} s later")
        time.sleep(max(0.0, t0 + max(down, cut) - time.monotonic()))
        tb.recover("r1")
        log(f"  r1 back {time.monotonic() - t0:.1f} s after the crash")
        results, error = [], ""
        for f in futs:
            try:
                results.append(f.result(600))
            except Exception as exc:  # lost: counted, and the first error said
                results.append(None)
                error = error or f"{type(exc).__name__}: {exc}"
        last = time.monotonic() - t0
        time.sleep(1.0)  # the origin's last trace lines
        trace = read_trace(tb.log_dir / "r1.trace.jsonl") if tb.log_dir else []
        gone = {e.program_id for r in names[1:] if tb.log_dir
                for e in read_trace(tb.log_dir / f"{r}.trace.jsonl") if e.what == "origin_gone"}
    delivered = Counter(e.program_id for e in trace if e.what == "delivered")
    resumed = sum(1 for e in trace if e.what == "restored")
    ok = [r is not None and r.get("iterations") == expected for r in results]
    # from the origin's trace (one clock with this process): where each ran at the crash, where it ended
    ran_at_crash = {e.program_id: e.other for e in trace if e.what == "accepted" and e.t < t0}
    ended = {e.program_id: (e.other, e.attempt) for e in trace if e.what == "delivered"}
    kept = sum(1 for pid, (host, attempt) in ended.items()
               if attempt == 1 and host != "r1" and ran_at_crash.get(pid) == host and pid not in gone)
    return RestartRun(down=down, cut=cut, programs=programs, delivered=sum(ok),
                      wrong=sum(1 for r, good in zip(results, ok) if r is not None and not good),
                      lost=sum(1 for r in results if r is None),
                      duplicated=sum(1 for n in delivered.values() if n > 1), kept=kept,
                      dropped=len(gone & set(ended)),
                      again=sum(1 for f in futs if f.attempts > 1), before=dict(sorted(before.items())),
                      resumed=resumed, seconds_to_last=round(last, 1), error=error)


class RollingRun(msgspec.Struct, kw_only=True):
    robots: int
    origins: list[str]
    submitted: int
    delivered: int
    lost: int
    duplicated: int
    wrong: int
    #: seconds each node took from its SIGTERM until it was back in the team
    restarts: dict[str, float]
    #: programs delivered per second before, during and after the roll
    rate_before: float
    rate_during: float
    rate_after: float
    seconds: float
    error: str = ""


def run_rolling_restart(*, robots: int = 8, origins: int = 3, period: float = 0.5, units: float = 0.3,
                        settle: float = 15.0, log: Callable[[str], None] | None = None) -> RollingRun:
    """Restart every node of a team one by one (``Testbed.restart``: SIGTERM,
    start again, wait until it is back) while ``origins`` applications, one
    per origin robot, each submit a ``units`` program every ``period`` s; the
    origins are restarted too. Counts lost, duplicated and wrong outcomes and
    the delivery rate before, during and after the roll."""
    import threading

    from ramps.testbed import Testbed
    from ramps.lab.experiments import read_trace

    log = log or (lambda _m: None)
    names = [f"r{i}" for i in range(1, robots + 1)]
    expected = round(units * ITERATIONS_PER_UNIT)
    roll_order = names[origins:] + names[:origins]  # hosts first, then the origins
    futs: list = []
    done_at: list[float] = []
    lock = threading.Lock()
    stop = threading.Event()
    with Testbed(names, cores=2) as tb:
        clients = [tb.client(o, timeout=30.0, origin_grace=120.0) for o in names[:origins]]
        try:
            time.sleep(SETTLE)

            def submitter(team) -> None:
                while not stop.is_set():
                    f = team.options(work=units).submit("burn", units=units)
                    f.add_done_callback(lambda _f: done_at.append(time.monotonic()))
                    with lock:
                        futs.append(f)
                    stop.wait(period)

            threads = [threading.Thread(target=submitter, args=(c,), daemon=True) for c in clients]
            t0 = time.monotonic()
            for th in threads:
                th.start()
            time.sleep(settle)
            roll_start = time.monotonic()
            restarts = {}
            for r in roll_order:
                restarts[r] = round(tb.restart(r, timeout=60.0), 1)
                log(f"  {r} restarted: back after {restarts[r]:.1f} s ({len(futs)} submitted, {len(done_at)} delivered)")
            roll_end = time.monotonic()
            time.sleep(settle)
            stop.set()
            for th in threads:
                th.join()
            end_submit = time.monotonic()
            results, error = [], ""
            for f in list(futs):
                try:
                    results.append(f.result(300))
                except Exception as exc:
                    results.append(None)
                    error = error or f"{type(exc).__name__}: {exc}"
            seconds = time.monotonic() - t0
            time.sleep(1.0)
            delivered: Counter = Counter()
            for o in names[:origins]:
                if tb.log_dir:
                    delivered.update(e.program_id for e in read_trace(tb.log_dir / f"{o}.trace.jsonl")
                                     if e.what == "delivered")
        finally:
            stop.set()
            for c in clients:
                c.close()

    def rate(a: float, b: float) -> float:
        return round(sum(1 for t in done_at if a <= t < b) / max(b - a, 1e-9), 2)

    return RollingRun(robots=robots, origins=names[:origins], submitted=len(futs),
                      delivered=sum(1 for r in results if r is not None and r.get("iterations") == expected),
                      lost=sum(1 for r in results if r is None),
                      duplicated=sum(1 for n in delivered.values() if n > 1),
                      wrong=sum(1 for r in results if r is not None and r.get("iterations") != expected),
                      restarts=restarts, rate_before=rate(t0 + 3.0, roll_start), rate_during=rate(roll_start, roll_end),
                      rate_after=rate(roll_end, end_submit), seconds=round(seconds, 1), error=error)
