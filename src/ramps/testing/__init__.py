"""Test helpers that ship with ramps, for its own tests and for yours.

``FakeTeam`` (``ramps.testing.fake``) joins real core nodes with an
in-memory network and an explicit clock: scenarios that run in
milliseconds, the same steps always giving the same result.

``MemoryTeam`` (``ramps.testing.memory``) runs the real node driver
(``NodeRuntime``) and core over an in-memory transport with a fake clock and
in-process programs: the driver's own logic (submit checks, handover,
overflow, reconnection) in milliseconds, without processes.

``LocalTeam`` (``ramps.testing.local``) is the other end: real ``ramps
node`` processes on this machine (loopback, free ports, multicast off,
optionally one cpu cgroup per robot), for end-to-end tests, the demo and
the benchmarks.
"""

from ramps.testing.fake import FakeTeam
from ramps.testing.local import LocalTeam, NodeProc, describe, tagged_processes
from ramps.testing.memory import FakeClock, MemoryBus, MemoryTeam, MemoryTransport

__all__ = ["FakeClock", "FakeTeam", "LocalTeam", "MemoryBus", "MemoryTeam", "MemoryTransport", "NodeProc", "describe",
           "tagged_processes"]
