"""The emulated team: robots on one Linux host, made, driven and broken.

This package is the emulated team only; the experiments run on it are
``ramps.lab``. How this works: ``Testbed(5)`` makes five robots, each a
network namespace on a shared bridge (``ramps.testbed.net``) and a cpu
cgroup whose programs are capped at their share (``ramps.testbed.caps``),
running a real ``ramps node``; ``crash``/``cut``/``freeze``/``recover``/
``lossy`` inject the faults of the paper (``ramps.testbed.bed``,
``ramps.testbed.faults``), ``ramps.testbed.stress`` a busy or half-dead
robot's, ``ramps.testbed.slowlink`` a slow link; ``ramps.testbed.sites`` is
two sites behind two routers. ``ramps testbed up|status|crash|...|down``
drives the same from the shell.

    from ramps.testbed import Testbed
    with Testbed(3, lease_ms=1000) as tb:
        team = tb.client("r1")
        team.submit("burn", seconds=0.2).result()
        tb.cut("r3"); tb.recover("r3")

Rules: root only; everything is removed on ``down()``/leaving the ``with``
block/SIGINT/SIGTERM; ``down_all()`` clears what crashed runs left.
"""

from ramps.testbed.bed import Testbed
from ramps.testbed.cleanup import down_all, leftovers
from ramps.testbed.procs import TestbedError

__all__ = ["Testbed", "TestbedError", "down_all", "leftovers"]
