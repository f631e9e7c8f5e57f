"""A randomized fault campaign on the testbed (``ramps testbed campaign``).

The real-process twin of ``ramps.experiments.campaign`` (``ramps sim campaign``).

How this works: ``run_campaign`` runs seeded ``run_campaign_once`` runs:
random crash / cut / freeze / recover faults of non-origin robots
(``campaign_plan``) during a workload of ``burn`` programs, then the
invariants: every program completed exactly once and every robot that was
recovered is back in the team (alive, publishing, not on the origin's
blacklist, and running programs again). With ``stress`` it also injects
what a busy or half-dead robot does (``stress_plan``, ``ramps.testbed.stress``:
node-only stalls, node-only crashes, CPU pressure, origin stalls and origin
crashes) and checks that nothing was restarted without cause (every
write-off or hedge at the origin falls inside an injected fault of that
host, never a stall of the origin itself: ``_unexplained``) and nothing was
left running (every robot idle, no orphaned worker; a node killed alone
leaves no process behind 1 s later).

An origin that crashes (its robot, or its node alone) and is started again
resumes its programs from its durable record (``ramps.runtime.store``):
hosts deliver to the new node what they kept running, its client asks
again for every pending program and gets each outcome once. A program
whose origin is not back within the client's grace (``ORIGIN_GONE_GRACE``)
fails with ``ProgramLost`` and the application submits it again
(``_wait_resubmitting``: to the same robot's node, once it is back),
counted as ``resubmitted``. Either way each program must complete once for
the application (checked: nothing left running after the run).

The testbed set-up, trace reading and fault injection are shared with the
paper's failure experiments (``ramps.lab.experiments``).
"""

from __future__ import annotations

import json
import random
import sys
import time
from concurrent.futures import wait as wait_futures
from pathlib import Path
from typing import TYPE_CHECKING, Callable

import msgspec

from ramps.errors import NoTeam, ProgramLost
from ramps.experiments.campaign import CampaignReport
from ramps.sim.engine import TraceEntry
from ramps.testbed import stress as stresses
from ramps.lab.experiments import (NAMES, _inject, _keep, _log_dir, delivered_counts, hosts_at,
                                       identical_speed, read_trace)

if TYPE_CHECKING:
    from ramps.runtime.watch import TeamWatcher
    from ramps.testbed import Testbed


class CampaignRun(msgspec.Struct, kw_only=True):
    seed: int
    robots: int
    programs: int
    faults: list[tuple[float, str, str]]
    completed: int
    lost: int
    duplicated: int
    not_rejoined: list[str]
    ok: bool
    seconds: float
    error: str = ""
    #: write-offs and hedges at the origin that no injected fault explains
    unexplained: list[str] = []
    #: robots with programs still running after the run, or orphaned workers
    left_running: list[str] = []
    #: processes of a node killed alone still running 1 s later (its workers must die with it)
    orphans: int = 0
    #: programs the application submitted again because their origin crashed (ProgramLost)
    resubmitted: int = 0


class TestbedCampaignReport(CampaignReport[CampaignRun], kw_only=True):
    """The simulator's campaign totals, with the testbed's runs (all kept: each is expensive)."""

    all_runs: list[CampaignRun] = []
    #: stopped by Ctrl-C: ``runs`` counts the runs that finished
    interrupted: bool = False
    unexplained_restarts: int = 0
    left_running: int = 0
    orphans: int = 0
    resubmitted: int = 0


def campaign_plan(rng: random.Random, robots: list[str], duration: float) -> list[tuple[float, str, str]]:
    """Random faults of the non-origin robots (the first robot is the origin):
    each gets 0-2 faults, each usually followed by a recovery; every robot is
    recovered by ``duration`` so the rejoin invariant can be checked."""
    faults: list[tuple[float, str, str]] = []
    for robot in robots[1:]:
        t = rng.uniform(0.5, duration * 0.3)
        for _ in range(rng.randint(0, 2)):
            if t > duration * 0.8:
                break
            faults.append((round(t, 2), robot, rng.choice(["crash", "cut", "freeze"])))
            t += rng.uniform(1.0, duration * 0.3)
            faults.append((round(min(t, duration * 0.9), 2), robot, "recover"))
            t += rng.uniform(0.5, duration * 0.2)
    return sorted(faults)


#: what a stressed campaign injects into robots other than the origin, and how often
STRESSES = ["crash", "cut", "freeze", "stall", "node_crash", "pressure", "pressure"]
#: seconds after a robot's recovery during which a write-off of it is still explained by its fault
EXPLAINED_AFTER = 5.0
#: what may happen to an origin (the robot whose node its application submits to), and how often
ORIGIN_FAULTS = ["stall", "stall", "node_crash", "crash"]
ORIGIN_FAULT_P = 0.5
#: times an application submits a program again after its origin crashed (ProgramLost)
RESUBMITS = 3


def stress_plan(rng: random.Random, robots: list[str], duration: float,
                origins: int = 1, origin_fault_p: float = ORIGIN_FAULT_P) -> list[tuple[float, str, str]]:
    """``campaign_plan`` with the stresses of a busy or half-dead robot
    (issue 14): besides crashes, cuts and freezes, a node stalled alone for
    0.5-5 s (``stall``, then ``recover``), a node killed alone (``node_crash``,
    then ``recover``), and host CPU pressure (``pressure:N``: N busy processes
    appear, ``unload``: they vanish) of robots that are not origins; each
    origin (the first ``origins`` robots) may stall for 0.5-2 s, and must
    then restart none of its programs, or crash (``crash``: the robot;
    ``node_crash``: its node alone) while its programs run elsewhere, and be
    recovered 1-4 s later."""
    faults: list[tuple[float, str, str]] = []
    for robot in robots[origins:]:
        t = rng.uniform(0.5, duration * 0.3)
        for _ in range(rng.randint(0, 3)):
            if t > duration * 0.8:
                break
            kind = rng.choice(STRESSES)
            if kind == "stall":
                faults.append((round(t, 2), robot, "stall"))
                t += rng.uniform(0.5, 5.0)
                faults.append((round(t, 2), robot, "recover"))
            elif kind == "pressure":
                faults.append((round(t, 2), robot, f"pressure:{rng.randint(2, 6)}"))
                t += rng.uniform(1.0, duration * 0.4)
                faults.append((round(min(t, duration * 0.9), 2), robot, "unload"))
            else:
                faults.append((round(t, 2), robot, kind))
                t += rng.uniform(1.0, duration * 0.3)
                faults.append((round(min(t, duration * 0.9), 2), robot, "recover"))
            t += rng.uniform(0.5, duration * 0.2)
    for origin in robots[:origins]:
        if rng.random() < origin_fault_p:
            t = rng.uniform(1.0, duration * 0.7)
            kind = rng.choice(ORIGIN_FAULTS)
            back = t + (rng.uniform(0.5, 2.0) if kind == "stall" else rng.uniform(1.0, 4.0))
            faults += [(round(t, 2), origin, kind), (round(back, 2), origin, "recover")]
    return sorted(faults)


def _unexplained(trace: list[TraceEntry], spans: dict[str, list[tuple[float, float]]], origin: str) -> list[str]:
    """Write-offs and hedges at the origin whose host had no fault then. A
    stall of the origin itself explains none: it must restart nothing.

    An attempt the origin resumed from its record after its own crash
    (``restored``) is written off at most ``RESTORE_GRACE`` after the restart
    when its host stays silent; that is explained when the origin never saw
    it accepted before the crash (the offer went down with it) or when its
    host had a fault between the placement and the write-off (the copy died
    while the origin was away)."""
    placed = {(e.program_id, e.attempt): e.t for e in trace if e.what == "placed"}
    accepted = {(e.program_id, e.attempt) for e in trace if e.what == "accepted"}
    restored = {(e.program_id, e.attempt): e.t for e in trace if e.what == "restored"}
    out = []
    for e in trace:
        if e.what not in ("failed", "suspected") or not e.other or e.other == origin and e.what == "suspected":
            continue
        if any(a <= e.t <= b for a, b in spans.get(e.other, []) if e.other != origin):
            continue
        key = (e.program_id, e.attempt)
        if key in restored and restored[key] <= e.t:
            if key not in accepted or any(a <= e.t and b >= placed.get(key, restored[key])
                                          for a, b in spans.get(e.other, []) if e.other != origin):
                continue
        out.append(f"{e.what} {e.program_id} attempt {e.attempt} on {e.other} ({e.detail}) at +{e.t:.1f}")
    return out


def run_campaign_once(seed: int, *, policy: str = "ramps", robots: int = 4, duration: float = 20.0,
                      lease_ms: int | None = None, discovery: str = "both", keep_logs: Path | None = None,
                      log: Callable[[str], None] | None = None, stress: bool = False,
                      told_speed: bool = False, origin_fault_p: float = ORIGIN_FAULT_P) -> CampaignRun:
    """One seeded run: a testbed of ``robots``, programs from r1 for about
    ``duration`` seconds under random faults, then the invariants. With
    ``keep_logs``, a failed run's node logs and traces are kept in
    ``keep_logs/campaign-<seed>``."""
    from ramps.testbed import Testbed
    from ramps.testbed.bed import watch_team

    log = log or (lambda _m: None)
    rng = random.Random(seed)
    names = [f"r{i}" for i in range(1, robots + 1)]
    if stress:  # one or two origins (r1, r2), each with its own application
        origins = names[:2] if robots >= 3 and rng.random() < 0.4 else names[:1]
        faults = stress_plan(rng, names, duration, origins=len(origins), origin_fault_p=origin_fault_p)
    else:
        origins = names[:1]
        faults = campaign_plan(rng, names, duration)
    n_programs = rng.randint(8, 24)
    units = [round(rng.uniform(0.05, 0.6), 3) for _ in range(n_programs)]
    spacing = duration * 0.6 / n_programs
    started = time.monotonic()
    futures = []
    orphans = 0
    left_running: list[str] = []
    spans: dict[str, list[tuple[float, float]]] = {}  # robot -> (fault began, recovered + EXPLAINED_AFTER)
    began: dict[str, float] = {}
    speed = identical_speed(robots, 2)
    with Testbed(names, cores=2, speed=speed if told_speed else None, policy=policy, lease_ms=lease_ms,
                 discovery=discovery) as tb, \
            watch_team(tb) as obs, \
            tb.client("r1", timeout=30.0) as team:
        teams = [team] + [tb.client(o, timeout=30.0) for o in origins[1:]]
        t0 = time.monotonic()
        timeline = sorted([(at, "fault", r, k) for at, r, k in faults] +
                          [(i * spacing, "submit", "", str(i)) for i in range(n_programs)])
        for at, what, robot, kind in timeline:
            time.sleep(max(0.0, t0 + at - time.monotonic()))
            if what == "submit":
                u = units[int(kind)]
                app = int(kind) % len(teams)
                futures.append((u, teams[app].options(work=u).submit("burn", units=u), app))
                continue
            orphans += _apply_fault(tb, robot, kind, began, spans, log)
            log(f"  t={time.monotonic() - t0:5.1f} s  {kind} {robot}")
        futures, resubmitted = _wait_resubmitting(futures, teams, log)
        completed, error = _outcomes(futures)
        not_rejoined = _not_rejoined(tb, obs, sorted({r for _, r, k in faults if k == "recover"}))
        time.sleep(0.2)
        traces = {o: read_trace(_log_dir(tb) / f"{o}.trace.jsonl") for o in origins}
        dup = sum(n - 1 for tr in traces.values() for n in delivered_counts(tr).values() if n > 1)
        for robot, at in began.items():  # faults never recovered explain what followed them
            spans.setdefault(robot, []).append((at, float("inf")))
        unexplained = [f"{o}: {u}" for o, tr in traces.items() for u in _unexplained(tr, spans, o)] if stress else []
        for t in teams[1:]:
            t.close()
        if stress:  # nothing left running: every robot idle, no orphaned worker
            left_running = _left_running(tb, obs, names)
        ok = n_programs == completed and dup == 0 and not not_rejoined and not unexplained and not left_running \
            and not orphans
        if keep_logs is not None and not ok:
            _keep(tb, Path(keep_logs) / f"campaign-{seed}")
    lost = n_programs - completed
    return CampaignRun(seed=seed, robots=robots, programs=n_programs, faults=faults, completed=completed, lost=lost,
                       duplicated=dup, not_rejoined=not_rejoined, ok=ok, seconds=round(time.monotonic() - started, 1),
                       error=error, unexplained=unexplained, left_running=left_running, orphans=orphans,
                       resubmitted=resubmitted)



def _apply_fault(tb: Testbed, robot: str, kind: str, began: dict[str, float],
                 spans: dict[str, list[tuple[float, float]]], log: Callable[[str], None]) -> int:
    """Inject one fault of a campaign's plan (or its recovery) into ``robot``;
    ``began`` and ``spans`` record when each robot's faults began and what they
    explain. Returns the processes a node-only crash left running."""
    if kind == "recover":
        tb.recover(robot, wait=False)
        if robot in began:
            spans.setdefault(robot, []).append((began.pop(robot), time.monotonic() + EXPLAINED_AFTER))
    elif kind.startswith("pressure:"):
        tb.add_load(robot, int(kind.split(":")[1]))
    elif kind == "unload":
        tb.remove_load(robot)
    elif kind == "stall":
        began.setdefault(robot, time.monotonic())
        stresses.stall_node(tb, robot)
    elif kind == "node_crash":
        began.setdefault(robot, time.monotonic())
        left = stresses.crash_node(tb, robot)
        if left:
            log(f"  node-only crash of {robot}: {len(left)} process(es) still running 1 s later: {left}")
        return len(left)
    else:
        began.setdefault(robot, time.monotonic())
        _inject(tb, robot, kind)
    return 0


def _outcomes(futures: list) -> tuple[int, str]:
    """(programs completed with the right result, the first error seen) of
    ``(units, future, application)`` triples; the futures still pending are cancelled."""
    completed, error = 0, ""
    done, pending = wait_futures([f for _, f, _ in futures], timeout=0)
    for u, f, _ in futures:
        if f in done and f.exception() is None and f.result().get("iterations") == round(u * 16_000_000):
            completed += 1
        elif f in done and f.exception() is not None:
            error = error or f"{type(f.exception()).__name__}: {f.exception()}"
    for f in pending:
        f.cancel()
    return completed, error


def _not_rejoined(tb: Testbed, obs: TeamWatcher, recovered: list[str]) -> list[str]:
    """Why robots are not back in the team: every robot is alive, and each of
    ``recovered`` publishing and not written off at r1, within 15 s."""
    not_rejoined: list[str] = []
    try:
        tb.wait_alive(timeout=60.0)
    except Exception as exc:  # NoTeam: named robots did not come back
        not_rejoined.append(str(exc).splitlines()[0])
    deadline = time.monotonic() + 15.0
    missing: list[str] = []
    r1 = None
    while time.monotonic() < deadline:
        rows = {row["robot"]: row for row in obs.view()}
        r1 = obs.report("r1")
        black = set(r1.blacklisted) if r1 else set()
        missing = [r for r in recovered if not rows.get(r, {}).get("alive") or r in black]
        if not missing:
            break
        time.sleep(0.5)
    else:
        not_rejoined += [f"{r} ({'blacklisted at r1' if r in black else 'not alive'}; r1 sees "
                         f"{r1.sees if r1 else '?'} others)" for r in missing]
    return not_rejoined


def _left_running(tb: Testbed, obs: TeamWatcher, names: list[str]) -> list[str]:
    """What is still running within 15 s: programs on a robot, orphaned workers."""
    deadline = time.monotonic() + 15.0
    while True:
        rows = {row["robot"]: row for row in obs.view()}
        left_running = [f"{r} runs {rows[r].get('running')}" for r in names if rows.get(r, {}).get("running")]
        left_running += [f"{r} orphans {o}" for r in names if (o := stresses.orphans(tb, r))]
        if not left_running or time.monotonic() > deadline:
            return left_running
        time.sleep(0.5)


def _wait_resubmitting(futures: list, teams: list, log, timeout: float = 600.0) -> tuple[list, int]:
    """Wait for every program; one that failed with ``ProgramLost`` (its
    origin crashed and was not back within the client's grace) is submitted
    again by its application, as the Team API says to, up to RESUBMITS
    times. Returns the final (units, future, application) list and how many
    were submitted again."""
    deadline = time.monotonic() + timeout
    entries = [[u, f, app, 0] for u, f, app in futures]
    resubmitted = 0
    while True:
        wait_futures([e[1] for e in entries], timeout=max(0.0, deadline - time.monotonic()))
        lost = [e for e in entries if e[1].done() and not e[1].cancelled()
                and isinstance(e[1].exception(), ProgramLost) and e[3] < RESUBMITS]
        if not lost or time.monotonic() >= deadline:
            break
        for e in lost:
            u, team = e[0], teams[e[2]]
            log(f"  program lost with its origin {team.robot} ({e[1].exception()}); submitted again")
            e[1], e[3] = team.options(work=u).submit("burn", units=u), e[3] + 1
            resubmitted += 1
    return [(u, f, app) for u, f, app, _ in entries], resubmitted


def run_campaign(runs: int, seed: int = 0, *, policy: str = "ramps", robots: int = 4, duration: float = 20.0,
                 lease_ms: int | None = None, discovery: str = "both", keep_logs: Path | None = None,
                 only_seed: int | None = None, progress=None, log=None, stress: bool = False,
                 told_speed: bool = False, origin_fault_p: float = ORIGIN_FAULT_P) -> TestbedCampaignReport:
    """``runs`` runs with seeds ``seed*1000000 + i``; with ``only_seed``, that
    one run seed ``runs`` times (to chase a failure a campaign printed)."""
    started = time.perf_counter()
    seeds = [only_seed] * runs if only_seed is not None else [seed * 1_000_000 + i for i in range(runs)]
    results = []
    interrupted = False
    for i, run_seed in enumerate(seeds):
        try:
            for attempt in (1, 2, 3):
                try:
                    results.append(run_campaign_once(run_seed, policy=policy, robots=robots, duration=duration,
                                                     lease_ms=lease_ms, discovery=discovery, keep_logs=keep_logs,
                                                     log=log, stress=stress, told_speed=told_speed,
                                                     origin_fault_p=origin_fault_p))
                    break
                except NoTeam as exc:  # the fresh testbed did not come up (a busy host): up to 3 tries
                    if attempt == 3:
                        raise
                    msg = (f"run seed {run_seed}: the testbed did not come up ({str(exc).splitlines()[0]}); "
                           "starting it again")
                    log(msg) if log else print(msg, file=sys.stderr)
        except KeyboardInterrupt:  # the run's testbed is already down: report the runs that finished
            interrupted = True
            break
        if progress:
            progress(i + 1, runs, results[-1])
    return TestbedCampaignReport(
        world="testbed", runs=len(results), interrupted=interrupted, seed=seed, policy=policy,
        programs=sum(r.programs for r in results),
        faults=sum(sum(1 for f in r.faults if f[2] != "recover") for r in results),
        completed=sum(r.completed for r in results), lost=sum(r.lost for r in results),
        duplicated=sum(r.duplicated for r in results), not_rejoined=sum(len(r.not_rejoined) for r in results),
        failed_runs=[r for r in results if not r.ok], all_runs=results, wall_seconds=time.perf_counter() - started,
        unexplained_restarts=sum(len(r.unexplained) for r in results),
        left_running=sum(len(r.left_running) for r in results), orphans=sum(r.orphans for r in results),
        resubmitted=sum(r.resubmitted for r in results))


# ====================================================================== re-placement per program
def replacement_per_program(report: dict, logs: Path) -> dict[str, list[float]]:
    """Per displaced program, seconds from its host's failure to its
    acceptance by another robot, by mode, from a ``ramps testbed experiment
    faults --keep-logs LOGS --out REPORT`` run (the report's per-failure
    ``recovery`` is the time until the *last* displaced program runs again).
    The failure time is the origin's first write-off of the robot less the
    recorded detection time."""
    out: dict[str, list[float]] = {}
    for exp in report["experiments"]:
        for run in exp["runs"]:
            d = Path(logs) / f"{run['plan'].replace(' ', '_').replace(':', '').replace(',', '-')}-{run['seed']}"
            trace = sorted(read_trace(d / "r1.trace.jsonl"), key=lambda e: e.t)
            for f in run["failures"]:
                robot = NAMES[f["robot"]]
                first = next((e.t for e in trace if e.what in ("failed", "blacklisted") and e.other == robot), None)
                if first is None or f["detection"] is None:
                    continue
                t_fail = first - f["detection"]
                done_before = {e.program_id for e in trace if e.what == "delivered" and e.t < t_fail}
                held = {p for p, h in hosts_at(trace, t_fail).items() if h == robot and p not in done_before}
                again: dict[str, float] = {}
                for e in trace:
                    if e.t >= t_fail and e.what == "accepted" and e.program_id in held and e.other != robot:
                        again.setdefault(e.program_id, e.t - t_fail)
                out.setdefault(exp["mode"], []).extend(again.values())
    return out


if __name__ == "__main__":  # python -m ramps.lab.campaign REPORT.json LOGS
    import statistics

    if len(sys.argv) != 3:
        sys.exit("usage: python -m ramps.lab.campaign REPORT.json LOGS  (of ramps testbed experiment "
                 "faults --out REPORT.json --keep-logs LOGS): per displaced program, failure to running again")
    for mode, values in replacement_per_program(json.loads(Path(sys.argv[1]).read_text()), Path(sys.argv[2])).items():
        values.sort()
        print(f"{mode}: {len(values)} displaced programs running again after median "
              f"{statistics.median(values):.2f} s (min {values[0]:.2f} s, max {values[-1]:.2f} s)")
