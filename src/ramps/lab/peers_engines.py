"""The engines of the peers experiment: ramps, round robin, Ray and Dask on a testbed each.

How this works: an ``Engine`` runs a scenario (``ramps.lab.peers_scenarios``)
on a fresh testbed of its own and says what happened (``EngineRun``, through
``_Burst``: when the burst started, where each program completed and when):

* ``RampsEngine``: ``ramps node`` on every robot with its default settings
  (no ``--speed``: the nodes measure themselves, the user's path), or one of
  its policies (``round_robin``); programs go through a ``Team`` client per
  origin, as in ``ramps.lab.sweeps``.
* ``ClusterEngine``: Ray or Dask on ``PeerBed``, a ``Testbed`` whose robots
  run that engine's node (``python -m ramps.lab.peers_robot node ...``)
  instead of ``ramps node``, and one driver per origin inside its robot
  (``ramps.lab.peers_robot``); the host reads where programs ran from
  the marks they leave on disk (``_running``) and their results from the
  drivers' files.

Every engine's busy robots get their load once it is up (``_load``), and a
crash (``_crash_when_due``) hits the robot running most programs that is
not an origin, ``crash_at`` s after the first submission.

Rules: one testbed at a time, taken down (every process of every robot,
and Ray's and Dask's with them) before ``run`` returns; a missing package
is said by ``missing``, with the extra to install.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, Protocol

from ramps.testbed.bed import Testbed
from ramps.lab.peers_scenarios import BUSY, SPACING, EngineRun, PeerScenario, Setup, distribution, victim
from ramps.testbed.procs import TestbedError

EXTRA = "pip install -e '.[peers]'  (or: pip install 'ramps-robotics[peers]')"


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
    from ramps.lab.experiments import SETTLE

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
                    from ramps.lab.experiments import _keep

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
    """A testbed whose robots run another engine's node (``python -m ramps.lab.peers_robot node``)
    instead of ``ramps node``: same namespaces, cgroups, caps, load and faults."""

    __test__ = False

    def __init__(self, engine: str, robots: int, **kw: Any) -> None:
        super().__init__(robots, **kw)
        self.engine = engine
        self.work_dir = Path(tempfile.mkdtemp(prefix=f"ramps-peers-{engine}-"))
        self._born = time.time()

    def _node_cmd(self, robot: str) -> list[str]:
        head = self.robots[self.names[0]]["ip"]
        return [self.python, "-m", "ramps.lab.peers_robot", "node", self.engine, robot, self.robots[robot]["ip"],
                head, str(self.cores), str(self.work_dir / robot)]

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
                argv = [tb.python, "-m", "ramps.lab.peers_robot", "drive", self.name, o, head,
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

