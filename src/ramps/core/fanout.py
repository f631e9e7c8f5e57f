"""Which origins hear a robot's load reports, in a team too big for all of them to.

How this works: in a small team every robot's reports go to every robot
that submits programs (an origin), and every origin can place on every
robot. A team of ``robots`` robots and ``origins`` origins that all hear
all carries robots x origins reports each period; at fleet size that is
most of the team's traffic and of each origin's work. So where the team has
more robots than ``placement_sample`` and more origins than
``report_fanout``, each report of a robot goes to ``report_fanout`` origins
only, from the robot's order of the origins by rendezvous hashing of
(origin, robot) (``report_order``): every robot computes it from names
alone, no message says it, and a robot joining or an origin leaving moves
only the pairs that involve it. Half of them are the first of that order,
the robot's home origins, which hear every report of it and so place on it
with fresh figures; the other half turns over the rest of the order, the
next ones at each periodic report (``turn_of``), so every origin hears
every robot now and then and sees where the team has room. Home origins
alone (a static split) left the origins that submitted last with only
their share of the team, full by then, while robots elsewhere waited:
300 robots, 30 origins, makespan 1.19x the capacity bound against 1.11x
with every report to every origin; with the turning half 1.10x
(docs/lab/2026-11-27-sim-scale-2.md).

Rules: pure functions of names and settings; no clock, no I/O.
"""

from __future__ import annotations

import hashlib
from collections.abc import Collection

from ramps.core.config import RampsConfig


def score(origin: str, robot: str) -> int:
    """The rendezvous weight of the pair: the same on every robot, in every process."""
    return int.from_bytes(hashlib.blake2b(f"{origin}\x00{robot}".encode(), digest_size=8).digest(), "big")


def report_order(robot: str, origins: Collection[str], team: int, config: RampsConfig) -> list[str] | None:
    """Every origin but ``robot``, in ``robot``'s rendezvous order (highest
    ``score`` first), in a team of ``team`` robots; None: every origin hears
    every report (a team of at most ``placement_sample`` robots, or of at
    most ``report_fanout`` origins besides this robot, or a fan-out of 0)."""
    fanout = config.report_fanout
    others = [o for o in origins if o != robot]
    if fanout <= 0 or team <= config.placement_sample or len(others) <= fanout:
        return None
    return sorted(others, key=lambda o: (-score(o, robot), o))


def report_targets(robot: str, origins: Collection[str], team: int, config: RampsConfig,
                   turn: int = 0) -> list[str] | None:
    """The origins that hear ``robot``'s ``turn``-th periodic load report
    (and its reports of the instant until the next), ``report_fanout`` of
    ``report_order`` (``turn_of``); None: all of them."""
    order = report_order(robot, origins, team, config)
    return None if order is None else turn_of(order, config.report_fanout, turn)


def turn_of(order: list[str], fanout: int, turn: int) -> list[str]:
    """The first half of ``fanout`` of ``order`` (the robot's home origins,
    every turn), then the ``turn``-th window of the other half over the rest
    of ``order``, round and round."""
    home = fanout // 2
    rest = order[home:]
    start = turn * (fanout - home) % len(rest)
    return order[:home] + (rest + rest)[start:start + fanout - home]
