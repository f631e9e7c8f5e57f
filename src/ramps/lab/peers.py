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
  client per origin, as in ``ramps.lab.sweeps``.
* ``ray``: a Ray head on the first robot and a Ray node on every robot
  (``ray start --num-cpus <cores>``), each in its robot's namespace and cgroup,
  and a driver per origin inside that origin's robot.
* ``dask``: a Dask scheduler on the first robot and ``dask worker --nthreads 1
  --nworkers <cores>`` (processes: the GIL) on every robot, a client per origin
  inside its robot.

Ray and Dask run on ``PeerBed``, a ``Testbed`` whose robots run that engine's
node (``python -m ramps.lab.peers_robot node ...``) instead of ``ramps
node``: the same namespaces, cgroups, caps, background load and crash. Their
programs are ``peer_burn``: ``ramps.programs.burn`` plus a mark on the host's
disk when it starts and ends (where it ran), so the crash picks a robot
running programs for every engine alike. Ray's and Dask's program processes
run at the niceness of ramps' workers (``worker_nice``, 10) so the capper and
the kernel share a busy robot between them and its own software exactly as
they do for ramps; their daemons run at nice 0 as ``ramps node`` does
(``Setup.peer_nice``, ``--peer-nice 0``: as Ray and Dask run out of the box;
the ideal then counts busy robots at nice 0). Beside 8 busy processes a
nice-10 program gets about a twentieth of a core: two programs placed there
(round robin) take 7 minutes, hence ``timeout``.

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
configuration (``ramps.lab.sweeps.simulate_config``; not for a crash).

The busy robots get their load once the engine is up (as ``ramps.lab.sweeps``
does): the engines' start-up is not what is compared, and Ray did not come up
beside a busy robot's load within 300 s.

Where each part is: the scenarios, the records, the ideal and the report in
``ramps.lab.peers_scenarios``; the engines, on the host, in
``ramps.lab.peers_engines``; what runs inside a robot for Ray and Dask in
``ramps.lab.peers_robot``; here, the engines by name (``ENGINES``) and
``run_peers``, which runs every scenario through every engine.

Rules: one engine's testbed at a time, taken down (every process of every
robot, and Ray's and Dask's with them) before the next; an engine whose package
is missing is skipped with the extra to install (``pip install
'ramps-robotics[peers]'``) and the others run.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Sequence

import msgspec

from ramps.lab.peers_engines import ClusterEngine, Engine, RampsEngine
from ramps.lab.peers_scenarios import EngineRun, PeerScenario, PeersReport, ScenarioResult, Setup, ideal, simulated

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
              repeats: int = 1, log: Callable[[str], None] | None = None) -> PeersReport:
    """Every scenario through every engine (module docstring), ``repeats``
    rounds of every engine in turns, each round starting with the next
    engine: the host's speed drifts by up to 25% between runs minutes apart,
    more than engines differ on idle robots, so a comparison of wall times
    takes each engine's median over rounds run in turns
    (``peers_scenarios.medians``)."""
    from ramps.lab.experiments import identical_speed

    log = log or (lambda _m: None)
    started = time.monotonic()
    chosen = [ENGINES[e]() for e in engines]
    out = []
    for sc in scenarios:
        log(f"{sc.name}: {sc.description}")
        runs: list[EngineRun] = []
        first: tuple[float, float, list[int]] | None = None  # speed, ideal, distribution
        # each round starts with the next engine: one that always ran first (after the previous
        # scenario's, or round's, last) would meet the host in a state of its own
        rounds = ((r, chosen[(r + k) % len(chosen)]) for r in range(repeats) for k in range(len(chosen)))
        for rnd, eng in rounds:
            why = eng.missing()
            if why:
                if rnd == 0:
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
                kept = setup if repeats == 1 or not setup.keep_logs else \
                    msgspec.structs.replace(setup, keep_logs=os.path.join(setup.keep_logs, f"round-{rnd + 1}"))
                run = eng.run(sc, kept, log)
            except Exception as exc:  # an engine that fails says so; the others run
                run = EngineRun(engine=eng.name, error=f"{type(exc).__name__}: {str(exc)[:2000]}")
            run.speed, run.round = speed, rnd + 1
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
                       scenarios=out, wall=round(time.monotonic() - started, 1), repeats=repeats)

