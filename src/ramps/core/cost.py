"""The cost model of the paper's eq. (1): move when T_here > T_there + T_comm.

How this works: a program's computation time on a robot is its work divided
by the speed one program gets there under processor sharing, ``speed *
min(1, cores / (runnable + 1))``, where ``runnable`` counts the tasks already
competing for the robot's cores (background processes and ramps programs) and
``+ 1`` is the program itself. Communication time is the request, the
acceptance and the result crossing the link: three latencies plus the bytes
of parameters and result over the bandwidth. Pure functions, no state.
"""

from __future__ import annotations

import msgspec


class NetworkEstimate(msgspec.Struct, frozen=True, kw_only=True):
    """What an origin believes about its links (from profiling, paper 3.2)."""

    latency: float = 0.005
    bandwidth: float = 2.5e6


def share(cores: int, runnable: float) -> float:
    """Fraction of one core a newly started task gets."""
    return min(1.0, cores / (runnable + 1.0))


def compute_time(work: float, cores: int, speed: float, runnable: float) -> float:
    """Seconds for ``work`` units on a robot with ``runnable`` competing tasks."""
    return work / (speed * share(cores, runnable))


def comm_time(payload: int, result: int, net: NetworkEstimate) -> float:
    """Seconds to offload parameters and bring the result back."""
    return 3.0 * net.latency + (payload + result) / net.bandwidth
