"""Test helpers that ship with ramps, for its own tests and for yours.

``FakeTeam`` (``ramps.testing.fake``) joins real core nodes with an
in-memory network and an explicit clock: scenarios that run in
milliseconds, the same steps always giving the same result.

``LocalTeam`` (``ramps.testing.local``) is the other end: real ``ramps
node`` processes on this machine (loopback, free ports, multicast off,
optionally one cpu cgroup per robot), for end-to-end tests, the demo and
the benchmarks.
"""

from ramps.testing.fake import FakeTeam
from ramps.testing.local import LocalTeam, NodeProc, describe, tagged_processes

__all__ = ["FakeTeam", "LocalTeam", "NodeProc", "describe", "tagged_processes"]
