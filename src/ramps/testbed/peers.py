"""ramps beside the engines users would pick instead: round robin, Ray and Dask
on the same emulated robots (issue 23, item 4).

How this works: a scenario (``SCENARIOS``) is a team of emulated robots
(``ramps.testbed``: a network namespace and a cpu cgroup of ``quota`` host
cores, ``cores`` emulated cores each, programs capped at their share by
``ramps.testbed.caps``), some of them busy with the testbed's background load,
and a burst of identical ``burn`` programs from one or more origins (each
origin submits its programs ``SPACING`` s apart, at the same moments), maybe
with one robot crashed (SIGKILL of everything it runs) ``crash_at`` s after the
first submission. Each engine runs the scenario on a fresh testbed of its own:

* ``ramps`` and ``round-robin``: ``ramps node`` on every robot with its default
  settings (no ``--speed``: the nodes measure themselves, the user's path),
  the second with ``policy="round_robin"``; programs go through a ``Team``
  client per origin, as in ``ramps.testbed.sweeps``.
* ``ray``: a Ray head on the first robot and a Ray node on every robot
  (``ray start --num-cpus <cores>``), each in its robot's namespace and cgroup,
  and a driver per origin inside that origin's robot.
* ``dask``: a Dask scheduler on the first robot and ``dask worker --nthreads 1
  --nworkers <cores>`` (processes: the GIL) on every robot, a client per origin
  inside its robot.

Ray and Dask run on ``PeerBed``, a ``Testbed`` whose robots run that engine's
node (``python -m ramps.testbed.peers node ...``) instead of ``ramps node``:
the same namespaces, cgroups, caps, background load and crash. Their programs
are ``peer_burn``: ``ramps.programs.burn`` plus a mark on the host's disk when
it starts and ends (where it ran), so the crash picks a robot running programs
for every engine alike. Ray's and Dask's program processes run at the niceness
of ramps' workers (``worker_nice``, 10) so the capper and the kernel share a
busy robot between them and its own software exactly as they do for ramps;
their daemons run at nice 0 as ``ramps node`` does (``Setup.peer_nice``, ``--peer-nice 0``: as Ray and Dask run out of the box; the
ideal then counts busy robots at nice 0). Beside 8 busy processes a nice-10
program gets about a twentieth of a core: two programs placed there (round
robin) take 7 minutes, hence ``timeout``.

What is printed per scenario and engine: the makespan (first submission to
last result), the distribution (programs per robot, where each completed),
programs lost, and the ideal makespan: the best schedule of the processor-sharing
model found by ``ramps.experiments.optimum``'s local search and annealing from the
oracle's (within a few percent of the optimum; the search's upper bound, not a proof)
for the scenario's releases on
robots of the speed measured before each run (a crashed robot is left out:
the ideal knows in hindsight). A busy robot's ``b`` processes count as
``b / nice_weight(worker_nice)`` programs, exact where the load fills the
robot's cores (weighted processor sharing: a program at nice 10 beside 8 busy
processes at nice 0 gets a tenth of what one of them gets). The host's speed
(a work unit's cost moves by 10-40% from minute to minute on a shared VM) is
measured before every run, so ``ratio`` = makespan / ideal at that speed
compares across days; ``sim`` is the simulator's ramps for the same
configuration (``ramps.testbed.sweeps.simulate_config``; not for a crash).

The busy robots get their load once the engine is up (as ``ramps.testbed.sweeps``
does): the engines' start-up is not what is compared, and Ray did not come up
beside a busy robot's load within 300 s.

Rules: one engine's testbed at a time, taken down (every process of every
robot, and Ray's and Dask's with them) before the next; an engine whose package
is missing is skipped with the extra to install (``pip install
'ramps-robotics[peers]'``) and the others run.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Protocol

import msgspec

from ramps.testbed.bed import Testbed
from ramps.testbed.procs import TestbedError

#: seconds between one origin's submissions (as ``ramps.testbed.sweeps``)
SPACING = 0.05
#: busy processes of a busy robot (the testbed's background load)
BUSY = 8
#: the niceness of ramps' program workers (``NodeSettings.worker_nice``), given to Ray's and Dask's too
WORKER_NICE = 10
RAY_PORT, DASK_PORT = 6379, 8786
EXTRA = "pip install -e '.[peers]'  (or: pip install 'ramps-robotics[peers]')"


class PeerScenario(msgspec.Struct, kw_only=True, frozen=True):
    name: str
    description: str
    robots: int = 5
    #: programs in all (split evenly between the origins)
    programs: int = 30
    #: busy robots (``BUSY`` processes each)
    loaded: tuple[str, ...] = ()
    origins: tuple[str, ...] = ("r1",)
    #: seconds after the first submission when a robot running programs is crashed (None: none)
    crash_at: float | None = None

    @property
    def names(self) -> list[str]:
        return [f"r{i}" for i in range(1, self.robots + 1)]

    def per_origin(self) -> int:
        return max(1, self.programs // len(self.origins))

    def with_programs(self, programs: int | None) -> "PeerScenario":
        return self if programs is None else msgspec.structs.replace(self, programs=programs)


SCENARIOS: dict[str, PeerScenario] = {s.name: s for s in (
    PeerScenario(name="idle", description="idle robots, programs from r1"),
    PeerScenario(name="busy-1", description="r5 busy (8 busy processes), programs from r1", loaded=("r5",)),
    PeerScenario(name="busy-2", description="r4 and r5 busy, programs from r1", loaded=("r4", "r5")),
    PeerScenario(name="busy-4", description="r2-r5 busy, programs from r1", loaded=("r2", "r3", "r4", "r5")),
    PeerScenario(name="origins", description="idle robots, r1 and r2 submit half each",
                 origins=("r1", "r2")),
    PeerScenario(name="crash", description="programs from r1; a robot running programs is crashed at 10 s",
                 programs=15, crash_at=10.0),
)}


class EngineRun(msgspec.Struct, kw_only=True):
    engine: str
    #: seconds from the first submission to the last result (None: nothing completed, or not run)
    makespan: float | None = None
    #: programs completed on each robot (the scenario's robots, r1 first)
    distribution: list[int] = []
    completed: int = 0
    lost: int = 0
    #: the robot crashed, and how many programs were running there then
    crashed: str | None = None
    crashed_running: int = 0
    #: work units per second of one emulated core, measured before the run; the ideal at that speed
    speed: float = 0.0
    ideal: float | None = None
    ratio: float | None = None
    host_load: float = 0.0
    wall: float = 0.0
    #: programs still running when the burst's time was up (``Setup.timeout``): no makespan then
    unfinished: int = 0
    #: host cores the busy robots' own software got during the burst, per busy robot (None: none busy):
    #: what the programs' priority protects (a robot's quota is ``Setup.quota``)
    own_cpu: float | None = None
    #: why it did not run, or failed
    error: str | None = None


class ScenarioResult(msgspec.Struct, kw_only=True):
    scenario: PeerScenario
    #: the ideal at the first run's speed, and its distribution
    ideal: float | None
    ideal_distribution: list[int]
    #: the simulator's ramps, median of 3 seeds (None with a crash)
    sim: float | None
    runs: list[EngineRun]


class PeersReport(msgspec.Struct, kw_only=True):
    cores: int
    quota: float
    work: float
    worker_nice: int
    scenarios: list[ScenarioResult]
    wall: float = 0.0


class Setup(msgspec.Struct, kw_only=True, frozen=True):
    cores: int = 4
    quota: float = 0.32
    work: float = 1.5
    #: seconds a burst may take (round robin's nice-10 programs beside 8 busy processes take 7-11 minutes)
    timeout: float = 1500.0
    #: niceness of Ray's and Dask's processes (ramps' workers keep the node's ``worker_nice``, 10)
    peer_nice: int = WORKER_NICE
    #: a folder where each ramps run's node logs and traces are kept (``<scenario>-<engine>/``)
    keep_logs: str | None = None


# ====================================================================== pure parts
def distribution(hosts: Sequence[str | None], names: Sequence[str]) -> list[int]:
    """Programs per robot (``names`` order) from where each completed program ran (None: lost)."""
    return [sum(1 for h in hosts if h == r) for r in names]


def releases(sc: PeerScenario) -> list[float]:
    """Every program's submission time from the first (the origins submit at the same moments)."""
    return sorted(i * SPACING for _ in sc.origins for i in range(sc.per_origin()))


def ideal(sc: PeerScenario, *, cores: int, speed: float, work: float, worker_nice: int = WORKER_NICE,
          without: Sequence[str] = (), time_limit: float = 3.0) -> tuple[float, list[int]]:
    """The best schedule of the processor-sharing model for the scenario (module docstring),
    without the robots ``without`` (a crashed one): the oracle's, improved by local search and
    annealing (``ramps.experiments.optimum``); its makespan and distribution."""
    from ramps.core.cost import nice_weight
    from ramps.experiments.metrics import Machine
    from ramps.experiments.optimum import anneal, improve
    from ramps.experiments.sweep import oracle_schedule
    from ramps.testbed.sweeps import sim_scenario

    names = [r for r in sc.names if r not in without]
    weight = nice_weight(worker_nice)
    team = [Machine(cores, speed, round(BUSY / weight) if r in sc.loaded else 0) for r in names]
    rel = releases(sc)
    # a feasible start: the oracle's on the same team (the simulator's scenario gives its machines)
    sim = sim_scenario(len(names), sc.per_origin(), 0, len(sc.origins), cores=cores, speed=speed, work=work)
    sim = msgspec.structs.replace(sim, robots=[msgspec.structs.replace(s, background=m.background)
                                               for s, m in zip(sim.robots, team)])
    _, start = oracle_schedule(sim, work)
    deadline = time.perf_counter() + time_limit
    span, placed = improve(team, rel, work, start, deadline)
    span, placed = min((span, placed), anneal(team, rel, work, placed, steps=20_000, deadline=deadline))
    counts = [0] * len(team)
    for i in placed:
        counts[i] += 1
    by_name = dict(zip(names, counts))
    return span, [by_name.get(r, 0) for r in sc.names]


def simulated(sc: PeerScenario, *, cores: int, speed: float, work: float) -> float | None:
    """The simulator's ramps for the scenario (``ramps.testbed.sweeps.simulate_config``); None with a
    crash, or with busy robots that are not the last ones (the sweeps' configurations)."""
    from ramps.testbed.sweeps import simulate_config

    last = sc.names[len(sc.names) - len(sc.loaded):] if sc.loaded else []
    if sc.crash_at is not None or sorted(sc.loaded) != sorted(last) or sc.origins != tuple(sc.names[:len(sc.origins)]):
        return None
    span, _ = simulate_config(sc.robots, sc.per_origin(), len(sc.loaded), len(sc.origins), cores=cores, speed=speed,
                              work=work)
    return round(span, 2)


def victim(running: dict[str, int], origins: Sequence[str]) -> str | None:
    """The robot to crash: of those running programs, not an origin, the one running most (the last on a tie)."""
    cands = [(n, r) for r, n in running.items() if n > 0 and r not in origins]
    return max(cands, key=lambda c: (c[0], c[1]))[1] if cands else None


def format_report(rep: PeersReport) -> str:
    lines = [f"robots of {rep.cores} emulated cores on {rep.quota:g} host cores, programs of {rep.work:g} units "
             f"of burn; Ray's and Dask's programs at nice {rep.worker_nice} (ramps' workers at the node's "
             f"worker_nice, 10); busy robots run {BUSY} "
             "busy processes"]
    for s in rep.scenarios:
        sc = s.scenario
        ideal_s = f"{s.ideal:.1f} s ({'-'.join(map(str, s.ideal_distribution))})" if s.ideal else "-"
        sim_s = f", simulator's ramps {s.sim:.1f} s" if s.sim else ""
        lines.append(f"\n{sc.name}: {sc.description}; {sc.robots} robots, {sc.per_origin() * len(sc.origins)} "
                     f"programs; ideal {ideal_s}{sim_s}")
        lines.append(f"  {'engine':12s} {'makespan':>9s} {'ideal':>7s} {'ratio':>6s} {'lost':>4s}  "
                     f"{'distribution':16s} notes")
        for r in s.runs:
            if r.error and r.makespan is None:
                lines.append(f"  {r.engine:12s} {'-':>9s} {'-':>7s} {'-':>6s} {'-':>4s}  {'':16s} {r.error}")
                continue
            span = f"{r.makespan:.1f} s" if r.makespan is not None else "-"
            notes = []
            if r.crashed:
                notes.append(f"crashed {r.crashed} with {r.crashed_running} running")
            if r.unfinished:
                notes.append(f"{r.unfinished} not done when the time was up")
            if r.own_cpu is not None:
                notes.append(f"busy robots' own software {r.own_cpu / rep.quota:.0%} of the robot")
            notes.append(f"speed {r.speed:.4f}, host load {r.host_load:.1f}")
            if r.error:
                notes.append(r.error)
            lines.append(f"  {r.engine:12s} {span:>9s} {(r.ideal or 0):7.1f} {(r.ratio or math.nan):6.2f} "
                         f"{r.lost:4d}  {'-'.join(map(str, r.distribution)):16s} {'; '.join(notes)}")
    lines.append(f"\nratio: makespan / ideal at the speed measured before that run; {rep.wall:.0f} s in all")
    return "\n".join(lines)


# ====================================================================== engines
class Engine(Protocol):
    """One engine: runs a scenario on a testbed of its own and says what happened."""

    name: str

    def missing(self) -> str | None:
        """Why it cannot run here (a package missing), or None."""

    def run(self, sc: PeerScenario, setup: Setup, log: Callable[[str], None]) -> EngineRun:
        """The scenario on a fresh testbed (taken down before returning)."""


class _Burst:
    """What an engine's programs did: when it started, and per program its host (None: not completed)
    and its end time. ``running()`` says, mid-burst, how many run on each robot."""

    def __init__(self, sc: PeerScenario) -> None:
        self.sc = sc
        self.t0: float | None = None
        self.hosts: list[str | None] = []
        self.ends: list[float] = []
        self.crashed: str | None = None
        self.crashed_running = 0
        #: programs still running when the time was up
        self.unfinished = 0
        #: the busy robots' own software's CPU seconds at the first submission (``own_cpu``)
        self.own_cpu0: float | None = None
        self.own_cpu: float | None = None

    def start(self, tb: Testbed, t0: float) -> None:
        """The burst starts at ``t0`` (monotonic)."""
        self.t0 = t0
        self.own_cpu0 = own_cpu(tb, self.sc)

    def stop(self, tb: Testbed) -> None:
        """The burst is over (done, or its time up): how much CPU the busy robots' own software got."""
        if self.own_cpu0 is None or self.t0 is None or not self.sc.loaded:
            return
        now, span = own_cpu(tb, self.sc), time.monotonic() - self.t0
        if now is not None and span > 0:
            self.own_cpu = round((now - self.own_cpu0) / span / len(self.sc.loaded), 4)

    def result(self, engine: str) -> EngineRun:
        done = [h for h in self.hosts if h is not None]
        span = max(self.ends) - self.t0 if self.ends and self.t0 is not None and not self.unfinished else None
        return EngineRun(engine=engine, makespan=round(span, 2) if span is not None else None,
                         distribution=distribution(self.hosts, self.sc.names), completed=len(done),
                         lost=self.sc.per_origin() * len(self.sc.origins) - len(done) - self.unfinished,
                         unfinished=self.unfinished, crashed=self.crashed, crashed_running=self.crashed_running,
                         own_cpu=self.own_cpu)


def own_cpu(tb: Testbed, sc: PeerScenario) -> float | None:
    """CPU seconds the busy robots' own processes (``Testbed.add_load``) have used so far
    (None: no busy robot)."""
    from ramps.runtime.measure import proc_cpu

    if not sc.loaded:
        return None
    total = 0.0
    for r in sc.loaded:
        for pid, _start in tb.robots[r]["load_pids"]:
            got = proc_cpu(pid)
            total += got[0] if got else 0.0
    return total


def _load(tb: Testbed, sc: PeerScenario) -> None:
    """The busy robots' load, once the engine is up (with the load there first, Ray was not up
    after 300 s and a raylet aborted: busy-1, 2026-11-26), then ``SETTLE`` s: the
    load adopted and capped, every robot's load report at every origin."""
    from ramps.testbed.experiments import SETTLE

    for r in sc.loaded:
        tb.add_load(r, BUSY)
    time.sleep(SETTLE if sc.loaded else 0.0)  # no load: the testbed was up once every robot saw every other


def _crash_when_due(tb: Testbed, burst: _Burst, running: Callable[[], dict[str, int]], stop: threading.Event,
                    log: Callable[[str], None]) -> threading.Thread | None:
    """A thread that crashes, ``crash_at`` s after the first submission, the robot ``victim`` picks."""
    at = burst.sc.crash_at
    if at is None:
        return None

    def crash() -> None:
        while burst.t0 is None and not stop.wait(0.05):
            pass
        if burst.t0 is None or stop.wait(max(0.0, burst.t0 + at - time.monotonic())):
            return
        now = running()
        r = victim(now, burst.sc.origins)
        if r is None:
            log(f"    nothing runs off the origins at {at:g} s: no crash")
            return
        tb.crash(r)
        burst.crashed, burst.crashed_running = r, now.get(r, 0)
        log(f"    crashed {r} at {time.monotonic() - burst.t0:.1f} s ({now.get(r, 0)} programs running there)")

    t = threading.Thread(target=crash, name="peers-crash", daemon=True)
    t.start()
    return t


class RampsEngine:
    """ramps with its default settings, or one of its policies (``round_robin``)."""

    def __init__(self, name: str = "ramps", policy: str | None = None, config: dict[str, Any] | None = None) -> None:
        self.name, self.policy, self.config = name, policy, config

    def missing(self) -> str | None:
        return None

    def run(self, sc: PeerScenario, setup: Setup, log: Callable[[str], None]) -> EngineRun:
        burst = _Burst(sc)
        futures: list[Any] = []
        with Testbed(sc.robots, cores=setup.cores, quota=setup.quota, speed=None, policy=self.policy,
                     config=self.config) as tb:
            clients = {o: tb.client(o, timeout=30.0) for o in sc.origins}
            stop = threading.Event()
            try:
                _load(tb, sc)

                def running() -> dict[str, int]:
                    out: dict[str, int] = {}
                    for f in list(futures):
                        if not f.done() and f.host:
                            out[f.host] = out.get(f.host, 0) + 1
                    return out

                crasher = _crash_when_due(tb, burst, running, stop, log)
                ends: dict[int, float] = {}
                t0 = time.monotonic()
                burst.start(tb, t0)
                for i in range(sc.per_origin()):
                    for o in sc.origins:
                        f = clients[o].options(work=setup.work).submit("burn", units=setup.work)
                        k = len(futures)
                        f.add_done_callback(lambda _f, k=k: ends.setdefault(k, time.monotonic()))
                        futures.append(f)
                    time.sleep(max(0.0, t0 + (i + 1) * SPACING - time.monotonic()))
                deadline = time.monotonic() + setup.timeout
                while not all(f.done() for f in futures) and time.monotonic() < deadline:
                    time.sleep(0.1)
                burst.stop(tb)
                stop.set()
                if crasher is not None:
                    crasher.join(5)
                if setup.keep_logs:
                    from ramps.testbed.experiments import _keep

                    time.sleep(0.3)  # the nodes' last trace lines
                    _keep(tb, Path(setup.keep_logs) / f"{sc.name}-{self.name}")
                for k, f in enumerate(futures):
                    ok = f.done() and not f.cancelled() and f.exception() is None
                    burst.hosts.append(f.host if ok else None)
                    if ok:
                        burst.ends.append(ends[k])
                    elif not f.done():
                        burst.unfinished += 1
                        f.cancel()
            finally:
                stop.set()
                for c in clients.values():
                    c.close()
        return burst.result(self.name)


# ---------------------------------------------------------------- Ray and Dask
class PeerBed(Testbed):
    """A testbed whose robots run another engine's node (``python -m ramps.testbed.peers node``)
    instead of ``ramps node``: same namespaces, cgroups, caps, load and faults."""

    __test__ = False

    def __init__(self, engine: str, robots: int, **kw: Any) -> None:
        super().__init__(robots, **kw)
        self.engine = engine
        self.work_dir = Path(tempfile.mkdtemp(prefix=f"ramps-peers-{engine}-"))
        self._born = time.time()

    def _node_cmd(self, robot: str) -> list[str]:
        head = self.robots[self.names[0]]["ip"]
        return [self.python, "-m", "ramps.testbed.peers", "node", self.engine, robot, self.robots[robot]["ip"], head,
                str(self.cores), str(self.work_dir / robot)]

    def wait_alive(self, robots: list[str] | None = None, timeout: float = 60.0) -> float:
        """The node processes run (the drivers wait until the engine sees every worker)."""
        time.sleep(0.5)
        for r in robots or self.names:
            if self.process_state(r) == "dead":
                raise TestbedError(f"the {self.engine} node of robot {r} exited at start:\n{self.log_tail(r)}")
        return 0.5

    def down(self) -> None:
        super().down()
        shutil.rmtree(self.work_dir, ignore_errors=True)
        _orphan_semaphores(self._born)



class ClusterEngine:
    """Ray or Dask: a ``PeerBed`` and one driver per origin inside its robot (``drive``)."""

    def __init__(self, name: str, module: str) -> None:
        self.name, self.module = name, module

    def missing(self) -> str | None:
        import importlib.util

        if importlib.util.find_spec(self.module) is None:
            return f"{self.module} is not installed: {EXTRA}"
        return None

    def run(self, sc: PeerScenario, setup: Setup, log: Callable[[str], None]) -> EngineRun:
        burst = _Burst(sc)
        tb = PeerBed(self.name, sc.robots, cores=setup.cores, quota=setup.quota)
        with tb:
            marks = tb.work_dir / "marks"
            marks.mkdir()
            head = tb.ip(tb.names[0])
            for o in sc.origins:
                argv = [tb.python, "-m", "ramps.testbed.peers", "drive", self.name, o, head,
                        str(sc.per_origin()), str(setup.work), str(sc.robots * setup.cores), str(tb.work_dir),
                        str(setup.peer_nice)]
                tb._spawn(o, argv, tb.work_dir / f"driver-{o}.log")
            ready = [tb.work_dir / f"ready-{o}" for o in sc.origins]
            deadline = time.monotonic() + 300.0
            while not all(p.exists() for p in ready):
                failed = [o for o in sc.origins if (tb.work_dir / f"result-{o}.json").exists()]
                if failed or time.monotonic() > deadline:
                    tails = "\n".join(_tail(tb.work_dir / f"driver-{o}.log") for o in sc.origins)
                    raise TestbedError(f"the {self.name} drivers did not see every worker within 300 s:\n{tails}")
                time.sleep(0.2)
            log(f"    {self.name}: every worker up")
            _load(tb, sc)
            stop = threading.Event()

            def running() -> dict[str, int]:
                return _running(marks)

            crasher = _crash_when_due(tb, burst, running, stop, log)
            t0 = time.monotonic() + 0.5
            (tb.work_dir / "go.tmp").write_text(repr(t0))
            (tb.work_dir / "go.tmp").replace(tb.work_dir / "go")
            burst.start(tb, t0)
            results = [tb.work_dir / f"result-{o}.json" for o in sc.origins]
            deadline = time.monotonic() + setup.timeout
            while not all(p.exists() for p in results) and time.monotonic() < deadline:
                time.sleep(0.2)
            burst.stop(tb)
            stop.set()
            if crasher is not None:
                crasher.join(5)
            errors = []
            for o, p in zip(sc.origins, results):
                try:
                    got = json.loads(p.read_text())
                except (OSError, ValueError):  # time is up: what the driver has seen so far
                    try:
                        got = json.loads(p.with_suffix(".partial").read_text())
                    except (OSError, ValueError):
                        got = {"programs": [], "error": f"no result from the driver on {o}"}
                if got.get("error"):
                    errors.append(f"{o}: {got['error']}")
                for prog in got["programs"]:
                    burst.hosts.append(prog["robot"] if prog.get("ok") else None)
                    if prog.get("ok"):
                        burst.ends.append(prog["end"])
                    burst.unfinished += bool(prog.get("pending"))
                burst.hosts += [None] * (sc.per_origin() - len(got["programs"]))
        run = burst.result(self.name)
        run.error = "; ".join(errors) or None
        return run


def _orphan_semaphores(since: float, shm: Path = Path("/dev/shm")) -> int:
    """Remove the named semaphores (``sem.mp-*``) made since ``since`` that no process maps any
    more: Dask's worker processes, SIGKILLed with their robot, leave about 24 a robot behind."""
    try:
        mine = [p for p in shm.glob("sem.mp-*") if p.stat().st_mtime >= since - 1.0]
    except OSError:
        return 0
    if not mine:
        return 0
    mapped: set[str] = set()
    for maps in Path("/proc").glob("[0-9]*/maps"):
        try:
            mapped.update(line.rsplit("/", 1)[-1] for line in maps.read_text().splitlines() if "/sem.mp-" in line)
        except OSError:
            continue
    gone = 0
    for p in mine:
        if p.name not in mapped:
            p.unlink(missing_ok=True)
            gone += 1
    return gone


def _tail(path: Path, lines: int = 15) -> str:
    try:
        return f"--- {path.name}:\n" + "\n".join(path.read_text(errors="replace").splitlines()[-lines:])
    except OSError:
        return f"--- {path.name}: (none)"


def _running(marks: Path) -> dict[str, int]:
    """Programs started and not ended, per robot, from ``peer_burn``'s marks."""
    try:
        names = os.listdir(marks)
    except OSError:
        return {}
    started = {n[len("start-"):] for n in names if n.startswith("start-")}
    ended = {n[len("end-"):] for n in names if n.startswith("end-")}
    out: dict[str, int] = {}
    for key in started - ended:
        robot = key.split("_")[2]
        out[robot] = out.get(robot, 0) + 1
    return out


ENGINES: dict[str, Callable[[], Engine]] = {
    "ramps": lambda: RampsEngine("ramps"),
    "round-robin": lambda: RampsEngine("round-robin", "round_robin"),
    # ramps with its programs at nice 0 (its default is 10): what that priority costs and protects
    "ramps-nice0": lambda: RampsEngine("ramps-nice0", config={"worker_nice": 0}),
    "ray": lambda: ClusterEngine("ray", "ray"),
    "dask": lambda: ClusterEngine("dask", "distributed"),
}
#: what a run compares when it names no engine (``ramps-nice0`` is the ablation of ramps' priority)
DEFAULT_ENGINES = ("ramps", "round-robin", "ray", "dask")


def run_peers(scenarios: Sequence[PeerScenario], engines: Sequence[str], setup: Setup = Setup(), *,
              log: Callable[[str], None] | None = None) -> PeersReport:
    """Every scenario through every engine (module docstring)."""
    from ramps.testbed.experiments import identical_speed

    log = log or (lambda _m: None)
    started = time.monotonic()
    chosen = [ENGINES[e]() for e in engines]
    out = []
    for sc in scenarios:
        log(f"{sc.name}: {sc.description}")
        runs: list[EngineRun] = []
        first: tuple[float, float, list[int]] | None = None  # speed, ideal, distribution
        for eng in chosen:
            why = eng.missing()
            if why:
                log(f"  {eng.name}: skipped, {why}")
                runs.append(EngineRun(engine=eng.name, error=f"skipped: {why}"))
                continue
            speed = identical_speed(1, setup.cores, setup.quota)  # the host's speed now, before the robots start
            if first is None:
                span, dist = ideal(sc, cores=setup.cores, speed=speed, work=setup.work, worker_nice=setup.peer_nice,
                                   without=sc.names[-1:] if sc.crash_at is not None else ())
                first = (speed, span, dist)
            t = time.monotonic()
            log(f"  {eng.name}: one emulated core runs {speed:.4f} units/s ...")
            try:
                run = eng.run(sc, setup, log)
            except Exception as exc:  # an engine that fails says so; the others run
                run = EngineRun(engine=eng.name, error=f"{type(exc).__name__}: {str(exc)[:2000]}")
            run.speed = speed
            run.ideal = round(first[1] * first[0] / speed, 2)
            run.ratio = round(run.makespan / run.ideal, 3) if run.makespan else None
            run.host_load = round(os.getloadavg()[0], 2)
            run.wall = round(time.monotonic() - t, 1)
            log(f"  {eng.name}: {run.makespan} s {run.distribution} lost {run.lost}"
                + (f" ({run.error})" if run.error else ""))
            runs.append(run)
        sim = simulated(sc, cores=setup.cores, speed=first[0], work=setup.work) if first else None
        out.append(ScenarioResult(scenario=sc, ideal=round(first[1], 2) if first else None,
                                  ideal_distribution=first[2] if first else [], sim=sim, runs=runs))
    return PeersReport(cores=setup.cores, quota=setup.quota, work=setup.work, worker_nice=setup.peer_nice,
                       scenarios=out, wall=round(time.monotonic() - started, 1))


# ====================================================================== inside a robot
def peer_burn(units: float, origin: str, index: int, marks: str, nice: int = WORKER_NICE) -> dict[str, Any]:
    """``burn`` as Ray's and Dask's program: at niceness ``nice`` (as ramps' workers run theirs; the
    worker process stays there, it only ever runs these), marking where it runs (start and end)
    on the host's disk."""
    from ramps.programs.burn import burn

    if os.getpriority(os.PRIO_PROCESS, 0) < nice:
        os.setpriority(os.PRIO_PROCESS, 0, nice)
    robot = os.environ.get("RAMPS_ROBOT", socket.gethostname())
    key = f"{origin}_{index}_{robot}_{os.getpid()}"
    Path(marks, f"start-{key}").touch()
    out = burn(units=units)
    Path(marks, f"end-{key}").touch()
    return {"robot": robot, "checksum": out["checksum"]}


def _node(engine: str, robot: str, ip: str, head: str, cores: int, work_dir: str) -> int:
    """A robot's node of ``engine``, at nice 0 as ``ramps node`` (its programs set their own
    niceness: ``peer_burn``); this process waits on it (the testbed's node pid)."""
    os.makedirs(work_dir, exist_ok=True)
    exe = Path(sys.executable).parent
    cmds: list[list[str]] = []
    if engine == "ray":
        common = ["--block", "--node-ip-address", ip, "--num-cpus", str(cores), "--num-gpus", "0",
                  "--object-store-memory", str(100 * 2**20), "--disable-usage-stats",
                  "--temp-dir", f"{work_dir}/ray"]  # a robot's own: sockets named alike in one session dir
        if ip == head:
            cmds.append([str(exe / "ray"), "start", "--head", "--port", str(RAY_PORT), "--include-dashboard",
                                "false", *common])
        else:
            _wait_port(head, RAY_PORT)
            cmds.append([str(exe / "ray"), "start", "--address", f"{head}:{RAY_PORT}", *common])
    elif engine == "dask":
        if ip == head:
            cmds.append([str(exe / "dask"), "scheduler", "--host", ip, "--port", str(DASK_PORT), "--no-dashboard"])
        cmds.append([str(exe / "dask"), "worker", f"tcp://{head}:{DASK_PORT}", "--host", ip, "--nthreads", "1",
                            "--nworkers", str(cores), "--no-dashboard", "--name", robot,
                            "--local-directory", work_dir])
    else:
        raise SystemExit(f"unknown engine {engine!r}")
    procs = [subprocess.Popen(c) for c in cmds]
    while all(p.poll() is None for p in procs):
        time.sleep(0.5)
    for p in procs:
        if p.poll() is None:
            p.kill()
    return 1


def _wait_port(host: str, port: int, timeout: float = 120.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            socket.create_connection((host, port), timeout=1.0).close()
            return
        except OSError:
            time.sleep(0.3)


def _drive(engine: str, origin: str, head: str, count: int, work: float, workers: int, work_dir: str,
           nice: int) -> None:
    """One origin's programs through ``engine``: connect, wait for every worker, write ``ready-<origin>``,
    wait for ``go`` (the first submission's monotonic time), submit ``count`` programs ``SPACING``
    apart, and write ``result-<origin>.json``: per program ok, robot and end time (and
    ``result-<origin>.partial`` after each completion, for a burst whose time runs out)."""
    d = Path(work_dir)
    marks = str(d / "marks")
    programs: list[dict[str, Any]] = []
    error = None

    def save(suffix: str) -> None:
        tmp = d / f"result-{origin}.tmp"
        tmp.write_text(json.dumps({"programs": programs, "error": error}))
        tmp.replace(d / f"result-{origin}.{suffix}")

    try:
        if engine == "ray":
            import ray

            ray.init(address=f"{head}:{RAY_PORT}", log_to_driver=False)
            while ray.cluster_resources().get("CPU", 0) < workers:
                time.sleep(0.5)
            task = ray.remote(num_cpus=1)(peer_burn)
        else:
            from distributed import Client, as_completed

            client = Client(f"tcp://{head}:{DASK_PORT}", timeout=120)
            client.wait_for_workers(workers, timeout=240)
        (d / f"ready-{origin}").touch()
        while not (d / "go").exists():
            time.sleep(0.01)
        t0 = float((d / "go").read_text())
        time.sleep(max(0.0, t0 - time.monotonic()))
        refs: list[Any] = []
        for i in range(count):
            if engine == "ray":
                refs.append(task.remote(work, origin, i, marks, nice))
            else:
                refs.append(client.submit(peer_burn, work, origin, i, marks, nice, pure=False,
                                          key=f"burn-{origin}-{i}"))
            time.sleep(max(0.0, t0 + (i + 1) * SPACING - time.monotonic()))
        programs = [{"ok": False, "pending": True} for _ in refs]
        if engine == "ray":
            index = {r: i for i, r in enumerate(refs)}
            pending = list(refs)
            while pending:
                done, pending = ray.wait(pending, num_returns=1)
                for r in done:
                    i, end = index[r], time.monotonic()
                    try:
                        programs[i] = {"ok": True, "robot": ray.get(r)["robot"], "end": end}
                    except Exception as exc:
                        programs[i] = {"ok": False, "error": f"{type(exc).__name__}: {exc}"[:300]}
                    save("partial")
        else:
            index = {f.key: i for i, f in enumerate(refs)}
            for f in as_completed(refs):
                i, end = index[f.key], time.monotonic()
                try:
                    programs[i] = {"ok": True, "robot": f.result()["robot"], "end": end}
                except Exception as exc:
                    programs[i] = {"ok": False, "error": f"{type(exc).__name__}: {exc}"[:300]}
                save("partial")
    except Exception as exc:
        error = f"{type(exc).__name__}: {exc}"[:1000]
    save("json")


def main(argv: list[str] | None = None) -> None:
    args = sys.argv[1:] if argv is None else argv
    if args[:1] == ["node"] and len(args) == 7:
        raise SystemExit(_node(args[1], args[2], args[3], args[4], int(args[5]), args[6]))
    if args[:1] == ["drive"] and len(args) == 9:
        _drive(args[1], args[2], args[3], int(args[4]), float(args[5]), int(args[6]), args[7], int(args[8]))
        os._exit(0)  # a client's threads must not hold the robot's process up
    print("usage: python -m ramps.testbed.peers node|drive ...  (started by ramps testbed experiment peers)",
          file=sys.stderr)
    raise SystemExit(2)


if __name__ == "__main__":
    main()
