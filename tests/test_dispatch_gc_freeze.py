"""A node's process leaves what its start-up made out of the garbage
collector's full passes (``gc.freeze`` once its driver runs): those objects
live as long as the process, and each full pass over them cost an origin
9-18 us per program in a burst (docs/lab/2026-11-28-dispatch-latency.md).
A node driven by its caller (``threaded=False``: ``MemoryTeam``, tests)
freezes nothing. Each case runs in a fresh interpreter."""

from __future__ import annotations

import subprocess
import sys

SCRIPT = """
import gc, sys
from ramps.runtime.node import NodeRuntime
from ramps.runtime.settings import load_settings
from ramps.testing.memory import MemoryBus, MemoryPool, StillSampler
threaded = sys.argv[1] == "threaded"
s = load_settings(flags={"robot": "r1", "team": "t", "cores": 2, "speed": 1.0, "battery_sysfs": False,
                         "state_dir": "off"}, environ={})
rt = NodeRuntime(s, transport=MemoryBus().transport("r1"), worker_pool=MemoryPool, load_sampler=StillSampler,
                 incarnation=1)
before = gc.get_freeze_count()
rt.start(threaded=threaded)
frozen = gc.get_freeze_count()
rt.stop()
print(before, frozen)
"""


def _frozen(mode: str) -> tuple[int, int]:
    out = subprocess.run([sys.executable, "-c", SCRIPT, mode], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    before, frozen = out.stdout.split()[-2:]
    return int(before), int(frozen)


def test_a_node_with_its_own_driver_freezes_what_its_start_made():
    before, frozen = _frozen("threaded")
    assert before == 0 and frozen > 1000  # the modules, the core, the transport: all of start-up


def test_a_node_its_caller_drives_freezes_nothing():
    assert _frozen("stepped") == (0, 0)
