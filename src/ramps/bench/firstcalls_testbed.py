"""``ramps bench first-calls --testbed``: the same first calls on an emulated team.

How this works: on loopback (``ramps.bench.firstcalls``) the team's three
nodes share this host's cores, so six calls at once share them too, and the
host alone sets the ratio's floor (about 2x-3x on two cores). A real team
of three robots has three computers. Here every round starts a fresh
testbed (``ramps.testbed.Testbed``, made by the ``make_testbed`` the
command hands in: ``ramps.bench`` does not import ``ramps.testbed``): each
robot a network namespace and a cpu cgroup of ``quota`` host cores split
into ``cores`` emulated cores of ``quota / cores`` host cores each, a
program's worker capped at one of them (``ramps.testbed.caps``), the nodes
told the same speed (1.0) as on loopback. The client is in the root
namespace and submits through r1, as on loopback. The same three phases
run (``firstcalls.measure``), with the same stages from the nodes' traces
(``<log dir>/<robot>.trace.jsonl``; their ``t`` is the host's monotonic
clock, which namespaces share) and the same CPU figures (a node's workers
are its fork server's children, whatever cgroup the capper moved them to).

The bound (``emulated_bound``) is ``firstcalls.bound`` with the emulated
team's cores for the host's: ``robots * cores`` cores, a call ``c`` =
its host CPU over ``quota / cores`` (what one emulated core takes to give
it that CPU), or, where longer, the time a call alone took from started to
finished. Three robots of one core: six calls, two a robot, end after 1 and
2 calls on each (median 1.5 calls: at least 1.5x), 2x if each robot shares
its core between its two; three robots of two cores: 1x. That bound
holds only while the host gives every robot its quota: the robots
together should take at most the host's cores, less what the client and
the capper need (``default_quota``: nine tenths of the host's cores
shared out), and other processes on the host (the load average, taken at
each phase) take from the robots as from anything else.

A quota holds over the kernel's CFS period, not within it: with the
kernel's 100 ms, a call of less CPU than its cap allows in a period
(``route_plan`` with 8 picks: 15-50 ms against 30 ms a period at 0.3 host
cores) runs at the host's speed, and six of them at once share the host's
cores, whatever robots they are on. So ``ramps bench first-calls
--testbed`` makes its robots with a 10 ms period (``--period-ms``;
``Testbed(period_us=)``), over which emulated cores hold for such calls;
``bound["host"]`` is also given: ``firstcalls.bound`` on this host's cores
with the calls' host CPU, the floor that calls shorter than a period's
quota meet on the testbed too (the larger of the two holds).
"""

from __future__ import annotations

import shutil
import time
from collections.abc import Callable
from contextlib import AbstractContextManager
from pathlib import Path
from types import SimpleNamespace
from typing import Any

from ramps.bench.firstcalls import (bound, host_cores, measure, program_kwargs, round_result, run_alone_ms,
                                    run_rounds, summary)

#: seconds between the testbed being up (every robot sees the others and publishes its
#: load) and the first burst: each robot's load server hears the others once more
SETTLE = 1.5
#: of the host's cores, the share the robots' quotas take by default (the rest: the
#: client and the capper, in the root cgroup)
TEAM_SHARE = 0.9


def default_quota(robots: int, cores_of_host: int | None = None) -> float:
    """Host cores per robot so that ``robots`` fit in ``TEAM_SHARE`` of the host's cores:
    0.6 for three robots on two cores."""
    return round(TEAM_SHARE * (cores_of_host or host_cores()) / robots, 3)


class EmulatedTeam:
    """A running testbed as ``firstcalls.measure`` reads it: each robot's node
    (its ``pid``, in the robot's namespace and cgroup) and their traces."""

    def __init__(self, tb: Any) -> None:
        self.tb = tb

    @property
    def nodes(self) -> dict[str, SimpleNamespace]:
        return {r: SimpleNamespace(pid=self.tb.robots[r]["pid"]) for r in self.tb.names}

    def traces(self) -> list[Path]:
        return sorted(Path(self.tb.log_dir).glob("*.trace.jsonl"))

    def keep(self, dest: Path) -> None:
        """Copy the nodes' logs and traces to ``dest`` before the testbed's ``down`` removes them."""
        dest.mkdir(parents=True, exist_ok=True)
        for f in Path(self.tb.log_dir).iterdir():
            if f.is_file():
                shutil.copy(f, dest / f.name)


def emulated_bound(calls: int, robots: int, cores: int, quota: float, cpu_s: float, seq_p50_ms: float,
                   run_alone: float | None = None) -> dict:
    """``firstcalls.bound`` on ``robots`` robots of ``cores`` emulated cores of ``quota / cores``
    host cores each, for calls of ``cpu_s`` host CPU (the module's docstring)."""
    core = quota / cores
    b = bound(calls, robots * cores, cpu_s / core, seq_p50_ms, run_alone)
    b.update(mode="testbed", robots=robots, cores_per_robot=cores, quota=quota, core_host_cores=core,
             host_cpu_ms=cpu_s * 1e3, team_host_cores=robots * quota)
    return b


def testbed_round(make_testbed: Callable[[], AbstractContextManager[Any]], *, robots: int, cores: int, quota: float,
                  calls: int, program: str, kwargs: dict, keep: Path | None = None) -> dict:
    """One round on a fresh testbed from ``make_testbed()`` (entered, and left at the end);
    with ``keep``, its nodes' logs and traces are copied there first."""
    t0 = time.perf_counter()
    with make_testbed() as tb:
        started_s = time.perf_counter() - t0
        team = EmulatedTeam(tb)
        with tb.client(tb.names[0], timeout=30.0) as client:
            time.sleep(SETTLE)
            try:
                m = measure(team, client, calls, program, kwargs, team.traces)
            finally:
                if keep is not None:
                    team.keep(keep)
    seq = m["warm_one_after_another"]
    cpu_s = seq["worker_cpu_per_call_ms"] / 1e3
    b = emulated_bound(calls, robots, cores, quota, cpu_s, seq["p50_ms"], run_alone_ms(m))
    b["host"] = bound(calls, host_cores(), cpu_s, seq["p50_ms"])  # within a CFS period (the docstring)
    return round_result(started_s, m, b)


def bench_first_calls_testbed(make_testbed: Callable[[], AbstractContextManager[Any]], *, robots: int = 3,
                              cores: int = 2, quota: float, calls: int = 6, rounds: int = 1,
                              program: str = "route_plan", picks: int = 8, show: Any = None,
                              keep_logs: Path | None = None) -> dict:
    """``firstcalls.bench_first_calls`` on a fresh testbed a round (``mode`` "testbed"):
    ``make_testbed`` makes ``robots`` robots of ``cores`` cores on ``quota`` host cores each;
    with ``keep_logs``, round i's node logs and traces go to ``keep_logs/round-<i>``."""
    kwargs = program_kwargs(program, picks)
    done = [0]

    def one() -> dict:
        done[0] += 1
        keep = Path(keep_logs) / f"round-{done[0]}" if keep_logs is not None else None
        return testbed_round(make_testbed, robots=robots, cores=cores, quota=quota, calls=calls, program=program,
                             kwargs=kwargs, keep=keep)

    results = run_rounds(rounds, one, show)
    return summary(results, mode="testbed", nodes=robots, cores=cores, quota=quota, calls=calls, program=program,
                   kwargs=kwargs, host_cores=host_cores())
