"""A real ramps team on this machine, for end-to-end tests.

``LocalTeam`` is ``ramps.testing.LocalTeam`` (the one harness, shared with
the demo and the benchmarks) with the tests' defaults: it starts ``ramps
node`` processes (``python -m ramps.cli node``) on loopback, each with its
own robot name and Zenoh listen port, all in one team whose name is unique
to the test, with multicast off and every node connecting to the first one
(gossip builds the mesh). Nodes register the programs of
``tests/e2eprogs.py`` and are started with ``RAMPS_ROBOT`` set, so a result
tells which robot ran it.

    with LocalTeam(3, tmp_path) as t:          # r1, r2, r3, all visible
        team = t.client("r1")                  # ramps.connect(...)
        team.submit("where", x=1).result(60)
        t.start_node("r4")                     # joins, waits until visible
        t.stop_node("r2")                      # SIGTERM, waits for the exit
        t.kill_node("r3")                      # SIGKILL of its process group

Everything the team starts (nodes, their workers, background load, CLI
runs) is tagged with ``RAMPS_E2E_RUN`` in its environment and killed on
exit, even when the test fails; ``leftover_processes()`` finds any that
survived. Node output goes to ``<tmp>/<robot>.log``; ``logs()`` returns it
for failure messages.

A secured team (``secure=True``): the team gets its own CA in
``<tmp>/team-ca``, every node its credentials (``credentials(name)``) and
``tls/`` endpoints, and ``client()`` / ``wait_visible`` connect with the
credentials of an application ``app``.

Cpu cgroups (root and a writable cgroup v1 or v2 cpu controller needed, see
``cgroup_support()``): each node runs in its own cgroup, so it measures its
own load (``load_scope`` auto), as emulated robots sharing one host do, and
``spawn(..., robot=...)`` starts background load inside a robot's cgroup.
By default (``cgroups=None``) the quota is every core of the host, which
throttles nothing: it only keeps each node's load reports to its own
processes, so the tests running beside it (pytest-xdist, other people's
work on the host) do not make every robot look busy and skew placements.
``cgroups=True`` sets the quota to ``quota_cores``; ``cgroups=False``, or a
host without cgroups, measures the whole host as before.
"""

from __future__ import annotations

import functools
import os
import subprocess
import time
import uuid
from pathlib import Path
from typing import Any

import psutil

from ramps import testing
from ramps.runtime.localteam import RobotCgroup, cgroup_mode
from ramps.testing import NodeProc, describe, tagged_processes

__all__ = ["LocalTeam", "NodeProc", "assert_no_leftovers", "cgroup_support", "leftover_processes", "wait_for"]

TESTS_DIR = Path(__file__).resolve().parent
#: unique to this pytest process: every process a LocalTeam starts carries it
RUN_ID = f"{os.getpid()}-{uuid.uuid4().hex[:8]}"
RUN_ENV = "RAMPS_E2E_RUN"

PROGRAMS = ("where", "spin", "sleepy", "fail", "big")

#: every process group started by any LocalTeam of this run (for the final check)
_STARTED: list[subprocess.Popen] = []


def leftover_processes(run_id: str = RUN_ID) -> list[psutil.Process]:
    """Live processes started by this test run (tagged in their environment)."""
    return tagged_processes(RUN_ENV, run_id)


def assert_no_leftovers(timeout: float = 10.0) -> None:
    """After a test module: no node, worker, load or CLI process this run
    started is alive (killed if so, and the check fails)."""
    deadline = time.monotonic() + timeout
    left = leftover_processes()
    while left and time.monotonic() < deadline:
        time.sleep(0.2)
        left = leftover_processes()
    for p in left:
        try:
            p.kill()
        except psutil.Error:
            pass
    assert not left, f"processes started by this test run survived it: {describe(left)}"
    assert all(p.poll() is not None for p in _STARTED)


# ---------------------------------------------------------------- cgroups
def cgroup_support() -> str | None:
    """None if this process may create cpu cgroups with a quota, else why not."""
    if os.geteuid() != 0:
        return "not root"
    mode = cgroup_mode()
    if mode is None:
        return "no writable cpu cgroup controller (v1 /sys/fs/cgroup/cpu or v2 with +cpu)"
    try:
        RobotCgroup(f"ramps-e2e-probe-{uuid.uuid4().hex[:8]}", 0.5, mode).remove()
    except OSError as exc:
        return f"cannot create a cpu cgroup: {exc}"
    return None


@functools.cache
def _cgroups_work() -> bool:
    return cgroup_support() is None


# ---------------------------------------------------------------- the team
class LocalTeam(testing.LocalTeam):
    """``ramps.testing.LocalTeam`` with the tests' defaults: the programs of
    ``tests/e2eprogs.py`` (importable by the nodes), 2 cores, speed 1, a 1 s
    lease, a team named ``e2e-<hex>``, no ``RAMPS_*`` settings inherited from
    the caller, every process tagged with this test run, ``t.marks`` for the
    programs' marks, and ``close()`` killing at once (no graceful stop)."""

    def __init__(self, n: int, tmp: Path, *, cores: int | None = 2, lease_ms: int = 1000,
                 cgroups: bool | None = None, quota_cores: float = 1.0, programs=PROGRAMS, **kw: Any) -> None:
        self.n = n
        if cgroups is None:  # measure each node's own load, throttle nothing (module docstring)
            quota: float | None = float(len(os.sched_getaffinity(0))) if _cgroups_work() else None
        else:
            quota = quota_cores if cgroups else None
        marks = Path(tmp) / "marks"
        env = {k: v for k, v in os.environ.items() if not k.startswith("RAMPS_")}
        env["PYTHONPATH"] = os.pathsep.join([str(TESTS_DIR)] + [p for p in [os.environ.get("PYTHONPATH")] if p])
        env[RUN_ENV] = RUN_ID
        env["RAMPS_E2E_MARKS"] = str(marks)
        super().__init__(n, tmp, team=f"e2e-{uuid.uuid4().hex[:12]}", cores=cores, speed=1.0, lease_ms=lease_ms,
                         programs=[f"e2eprogs:{p}" for p in programs], cpu_quota=quota,
                         env=env, graceful=False, **kw)
        self.marks = marks
        self.marks.mkdir(exist_ok=True)

    def _popen(self, argv, *, log, env):
        p = super()._popen(argv, log=log, env=env)
        _STARTED.append(p)
        return p

    def cli(self, *args: str, timeout: float = 60.0):
        res = super().cli(*args, timeout=timeout)
        _STARTED.append(self._procs[-1])
        return res


def wait_for(pred, timeout: float, what: str, poll: float = 0.05):
    """Poll ``pred`` until it returns something true (returned), or fail
    saying ``what`` did not happen within ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while True:
        value = pred()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout:g} s waiting for {what}")
        time.sleep(poll)
