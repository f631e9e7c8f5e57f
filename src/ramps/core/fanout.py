"""Which origins hear a robot's load reports, in a team too big for all of them to.

How this works: in a small team every robot's reports go to every robot
that submits programs (an origin), and every origin can place on every
robot. A team of ``robots`` robots and ``origins`` origins that all hear
all carries robots x origins reports each period; at fleet size that is
most of the team's traffic and of each origin's work. So where the team has
more robots than ``placement_sample`` and more origins than
``report_fanout`` (0, the default: off), each robot reports to
``report_fanout`` origins only, the first of its order of the origins by
rendezvous hashing of (origin, robot) (``report_order``): every robot
computes it from names alone, no message says it, an origin hears about
robots x fanout / origins robots (its view, which is all it places on), and
a robot joining or an origin leaving moves only the pairs that involve it.

What it costs placement (docs/lab/2026-11-27-sim-scale-2.md): where
origins submit one after another and the team's capacity is tight, the
origins that submit last have only their share of the team, full by then,
while robots elsewhere wait with room: 3,000 robots, 30 origins, 16 each,
makespan 1.24x the capacity bound; 300 robots, 30 origins, 8 each, 1.19x
against 1.11x with every report to every origin. Turning half the targets
over the other origins at each report balanced 300 robots (1.10x) but not
3,000 (1.26x, 21 times the rejections) and made each origin's view the
whole team again. So it is off unless a team sets it: traffic bounded per
robot against placement's quality.

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


def report_targets(robot: str, origins: Collection[str], team: int, config: RampsConfig) -> list[str] | None:
    """The origins that hear ``robot``'s load reports: the first
    ``report_fanout`` of ``report_order``; None: all of them."""
    order = report_order(robot, origins, team, config)
    return None if order is None else order[:config.report_fanout]
