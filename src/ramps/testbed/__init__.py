"""Emulated robots on one Linux host: namespaces, cgroups, fault injection.

How this works: ``Testbed(5)`` makes five robots, each a network namespace
on a shared bridge (``ramps.testbed.net``) and a cpu cgroup, running a real
``ramps node``; ``crash``/``cut``/``freeze``/``recover`` inject the faults
of the paper (``ramps.testbed.bed``); ``ramps.testbed.detect`` measures how
fast the team notices them. ``ramps testbed ...`` drives the same from the
shell.

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
