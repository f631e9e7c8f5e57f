"""Teammates this robot hears one way only.

How this works: after a lease that expired on one side only, where both
robots had dialled each other, Zenoh can leave their session split for good
(eclipse-zenoh/zenoh#2806, seen in the field for days, until a restart): one
side no longer receives the other's declarations, so its messages to it go
nowhere, while the other's still arrive. Seen from each side, a teammate is
then either *alive* by its liveliness token yet none of its load reports
arrive (where this robot hears periodic reports: it places programs), or its
reports arrive while its liveliness token is gone. Either, for longer than
``ONE_WAY_AFTER``, is noted once (``one_way``), and again when it ends
(``two_way``); the driver logs a warning. A teammate whose node is stalled
while its Zenoh threads still answer looks the same from here, and is worth
the same warning. Placement needs none of this (a robot without a fresh
report is no candidate, one that does not answer is blacklisted): it is what
tells the operator, who heals it by restarting either node.
"""

from __future__ import annotations

from ramps.core.events import Note
from ramps.core.loadview import LoadView

#: seconds a teammate may be heard one way only before it is noted
ONE_WAY_AFTER = 30.0


class OneWay:
    """What liveliness says of each teammate, against its reports in ``LoadView``."""

    def __init__(self, me: str) -> None:
        self.me = me
        #: teammate -> since when its liveliness token is here (alive) or gone (lost)
        self.alive: dict[str, float] = {}
        self.lost: dict[str, float] = {}
        self.noted: dict[str, str] = {}
        #: since when this robot hears periodic reports (None: it does not)
        self.hearing_since: float | None = None

    def peer_alive(self, robot: str, now: float) -> None:
        if robot != self.me:
            self.alive.setdefault(robot, now)
            self.lost.pop(robot, None)

    def peer_lost(self, robot: str, now: float) -> None:
        if robot != self.me:
            self.alive.pop(robot, None)
            self.lost.setdefault(robot, now)

    def check(self, view: LoadView, now: float, hears_reports: bool) -> list[Note]:
        """Notes for teammates heard one way only since the last check, and
        for those heard both ways again. ``hears_reports``: this robot
        subscribes to its teammates' periodic reports (it places programs)."""
        if not hears_reports:
            self.hearing_since = None
        elif self.hearing_since is None:
            self.hearing_since = now
        out: list[Note] = []
        for robot in sorted(self.alive.keys() | self.lost.keys() | self.noted.keys()):
            why = self._one_way(robot, view, now)
            if why and robot not in self.noted:
                self.noted[robot] = why
                out.append(Note(what="one_way", robot=robot, detail=why))
            elif not why and robot in self.noted:
                del self.noted[robot]
                out.append(Note(what="two_way", robot=robot, detail="heard both ways again"))
        return out

    def _one_way(self, robot: str, view: LoadView, now: float) -> str:
        age = view.report_age(robot, now)
        if robot in self.alive and self.hearing_since is not None:
            silent = min(now - self.alive[robot], now - self.hearing_since, age if age is not None else now)
            if silent > ONE_WAY_AFTER:
                return (f"alive (its liveliness token is here) but no load report for {silent:.0f} s: "
                        "what it sends does not reach this robot")
        if robot in self.lost and age is not None and age < ONE_WAY_AFTER / 3 \
                and now - self.lost[robot] > ONE_WAY_AFTER:
            return (f"its load reports arrive (the last {age:.0f} s ago) but its liveliness token has been gone "
                    f"for {now - self.lost[robot]:.0f} s: what this robot sends may not reach it")
        return ""
