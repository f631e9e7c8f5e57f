"""Who a node is: its incarnation, and two nodes under one robot name.

How this works: a node draws its incarnation once, as it starts: its start
time in milliseconds (Unix time, by its machine's clock) followed by
``DRAW_BITS`` random bits (``new_incarnation``). So whoever compares two
incarnations of one robot name knows which node started later: the larger
one. A restarted node gets a larger incarnation than its previous process
had, and a load view that sees the incarnation change knows the robot
restarted (``ramps.core.loadview``). Two nodes started in the same
millisecond are ordered by their random bits, the same way by both.

Two nodes under one robot name (machines cloned from one disk image share
their host name, the default name; a second ``ramps node`` started by
mistake) hear each other's load reports: this robot's name, another
incarnation. ``SameName`` tells such a node from this robot's previous
process, whose last reports may still be on their way when a restarted node
starts: those come together, sent before that process ended, while a live
node reports every period. So a clash is reports of one other incarnation
with two sequence numbers, heard at least ``SAME_NAME_SPAN`` seconds apart.
Then the node that started later, the larger incarnation, leaves, and the
one that was already running (its programs, its clients) stays. Both
decide the same whichever hears the other first: ``NameTaken`` says which
to each, and the driver acts.

Rules: no clock, no I/O: the start time, the random draw and ``now`` come
in. Start times are compared across machines, so "later" holds as far as
their clocks agree (NTP, chrony); a node tells its user both start times.
An incarnation of ramps 0.1.0 (48 random bits) reads as a start in January
1970 (``started_at`` gives None), so a 0.1.0 node stays and the newer one
leaves, which is what both decide.
"""

from __future__ import annotations

from ramps.core.events import NameTaken
from ramps.core.messages import LoadReport

#: random bits under an incarnation's start time: ties within a millisecond
DRAW_BITS = 20
DRAW_MASK = (1 << DRAW_BITS) - 1
#: seconds between two reports of another incarnation before it counts as a
#: live node (a report period is 1 s by default): a dead process's last
#: reports reach a restarted node together
SAME_NAME_SPAN = 0.5
#: other incarnations kept in mind (a sender inventing them forgets the oldest)
MAX_OTHERS = 64
#: start times before this (2020-01-01, Unix seconds) are not start times:
#: an incarnation drawn otherwise (ramps 0.1.0, tests)
EARLIEST_START = 1_577_836_800.0


def new_incarnation(started: float, draw: int) -> int:
    """The incarnation of a node that started at ``started`` (Unix seconds)
    and drew ``draw`` (its low ``DRAW_BITS`` are used)."""
    return (max(0, int(started * 1000)) << DRAW_BITS) | (draw & DRAW_MASK)


def leaves(mine: int, other: int) -> bool:
    """Of two nodes under one robot name, whether the one of incarnation
    ``mine`` is the one that leaves: the one started later."""
    return mine > other


def started_at(incarnation: int) -> float | None:
    """When the node of ``incarnation`` started (Unix seconds, by its clock),
    or None if the incarnation holds no start time."""
    t = (incarnation >> DRAW_BITS) / 1000
    return t if t >= EARLIEST_START else None


class SameName:
    """Reports under this robot's name from other incarnations, as heard;
    ``heard`` says when they are a second node (see the module docstring)."""

    __slots__ = ("incarnation", "_seen")

    def __init__(self, incarnation: int) -> None:
        self.incarnation = incarnation
        #: other incarnation -> (first report's seq, when heard, told)
        self._seen: dict[int, tuple[int, float, bool]] = {}

    def seen(self) -> dict[int, int]:
        """The other incarnations heard, with their first report's seq."""
        return {inc: rec[0] for inc, rec in self._seen.items()}

    def heard(self, report: LoadReport, now: float) -> NameTaken | None:
        """A report of this robot from another incarnation: the clash, the
        first time one is certain, else None."""
        other = report.incarnation
        rec = self._seen.get(other)
        if rec is None:
            if len(self._seen) >= MAX_OTHERS:
                self._seen.pop(next(iter(self._seen)))
            self._seen[other] = (report.seq, now, False)
            return None
        seq, first_at, told = rec
        if told or report.seq == seq or now - first_at < SAME_NAME_SPAN:
            return None
        self._seen[other] = (seq, first_at, True)
        return NameTaken(other=other, leave=leaves(self.incarnation, other))
