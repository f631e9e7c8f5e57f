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

``hostile`` (``ramps.testing.hostile``) makes what a broken or hostile peer
may send: valid messages at their limits and mutated, truncated, oversized
or foreign bytes (``WIRE_KINDS``), one seeded ``random.Random`` each, for
testing code that handles ramps messages (``ramps bench fuzz`` runs them).
"""

from ramps.testing import hostile
from ramps.testing.fake import FakeTeam
from ramps.testing.hostile import WIRE_KINDS, random_message
from ramps.testing.local import LocalTeam, NodeProc
from ramps.testing.procs import describe, tagged_processes
from ramps.testing.memory import FakeClock, MemoryBus, MemoryTeam, MemoryTransport

__all__ = ["FakeClock", "FakeTeam", "LocalTeam", "MemoryBus", "MemoryTeam", "MemoryTransport", "NodeProc", "WIRE_KINDS",
           "describe", "hostile", "random_message", "tagged_processes"]
