"""Which origins hear a robot's load reports, in a team too big for all of them to.

How this works: in a small team every robot's reports go to every robot
that submits programs (an origin), and every origin can place on every
robot. A team of ``robots`` robots and ``origins`` origins that all hear
all carries robots x origins reports each period; at fleet size that is
most of the team's traffic and of each origin's work. So where the team has
more robots than ``placement_sample`` and more origins than
``report_fanout``, each robot reports to ``report_fanout`` origins only,
chosen by rendezvous hashing of (origin, robot): every robot computes the
same choice from names alone, no message says it, an origin hears about
robots x fanout / origins robots (its view, which is all it places on), and
a robot joining or an origin leaving moves only the pairs that involve it.
Each robot is in the views of ``report_fanout`` origins, so its load is
still shared between the origins that place on it, and an origin prices
its programs against a view of a bounded size (``placement_sample``'s short
list prices fewer still).

Rules: pure functions of names and settings; no clock, no I/O.
"""

from __future__ import annotations

import hashlib
from collections.abc import Collection

from ramps.core.config import RampsConfig


def score(origin: str, robot: str) -> int:
    """The rendezvous weight of the pair: the same on every robot, in every process."""
    return int.from_bytes(hashlib.blake2b(f"{origin}\x00{robot}".encode(), digest_size=8).digest(), "big")


def report_targets(robot: str, origins: Collection[str], team: int, config: RampsConfig) -> list[str] | None:
    """The origins that hear ``robot``'s load reports, other than itself, in
    a team of ``team`` robots of which ``origins`` submit programs; None: all
    of them (a team of at most ``placement_sample`` robots, or of at most
    ``report_fanout`` origins besides this robot, or a fan-out of 0)."""
    fanout = config.report_fanout
    others = [o for o in origins if o != robot]
    if fanout <= 0 or team <= config.placement_sample or len(others) <= fanout:
        return None
    return sorted(others, key=lambda o: (-score(o, robot), o))[:fanout]
