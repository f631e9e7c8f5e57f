"""Two nodes under one robot name: which one leaves, and both say why.

How this works: ``SameName`` is a part of the node's driver
(``ramps.runtime.node``). Every node declares a ``where`` token (its
incarnation and where it listens, ``keys.where``) and watches those under
its own robot name (``on_where``), so that when the core finds another node
under this name (``NameTaken``, ``ramps.core.identity``: the one that
started later leaves) ``clash`` can say where the other listens and when
each started, by their incarnations. The node that leaves keeps why
(``taken``) for the CLI's last line.

A node that started later may hear this one's reports, and leave, before
this one has heard two of its own (the core's proof of a live node), so the
node that stays also says so when the later node's ``where`` token comes:
a token under this robot's name of a larger incarnation than its own is a
node started while this one runs. Each other node is told of once.
"""

from __future__ import annotations

import logging
import threading
import time

from ramps.core.events import NameTaken
from ramps.core.identity import leaves, started_at
from ramps.runtime import keys
from ramps.runtime.node_trace import NodeTrace

log = logging.getLogger("ramps.node")
#: how to end a clash of names, said by both nodes
FIX = ("give each machine its own robot name: --robot NAME or RAMPS_ROBOT=NAME (the default name is "
       "the host name, which machines cloned from one disk image share)")


def _started(other: float | None, mine: float | None, order: str) -> str:
    """When another node started, as its incarnation tells, for a log line:
    "at 2026-11-27 10:31:05 UTC (12.3 s before this one, by the two machines' clocks)"."""
    if other is None:
        return "at a time its incarnation does not tell (ramps 0.1.0)"
    when = time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime(other))
    if mine is None:
        return f"at {when}"
    return f"at {when} ({abs(mine - other):.1f} s {order} this one, by the two machines' clocks)"


class SameName:
    """Robot ``robot``'s node of team ``team`` and the others under its name."""

    def __init__(self, team: str, robot: str, trace: NodeTrace) -> None:
        self.team = team
        self.robot = robot
        self.trace = trace
        #: where each node under this robot's name listens, by incarnation (``keys.where``)
        self.endpoints_of: dict[int, list[str]] = {}
        #: why this node left, another under its name having started first ("" = it did not)
        self.taken = ""
        #: this node's incarnation (set as it starts; 0: not yet)
        self.incarnation = 0
        #: the other nodes' incarnations already told of (the transport's and the driver's threads)
        self._told: set[int] = set()
        self._lock = threading.Lock()

    def on_where(self, key: str, declared: bool) -> None:
        """A ``where`` token of a node under this robot's name came or went (a transport callback)."""
        found = keys.where_of(key)
        if found is None:
            return
        _robot, other, endpoints = found
        if not declared:
            self.endpoints_of.pop(other, None)
            return
        self.endpoints_of[other] = endpoints
        if self.incarnation and leaves(other, self.incarnation):
            self._stays(other)  # a node started while this one runs: it is to leave

    def _first(self, other: int) -> bool:
        """Whether ``other`` is told of for the first time (and now is)."""
        with self._lock:
            new = other not in self._told
            self._told.add(other)
            return new

    def _at(self, other: int) -> str:
        """Where the node of incarnation ``other`` listens, as its token says,
        for a log line (" listening on tcp/...", or "" when not known)."""
        where = self.endpoints_of.get(other)
        return f" listening on {', '.join(where)}" if where else ""

    def _stays(self, other: int) -> None:
        """Say once that the node of incarnation ``other`` leaves and this one stays."""
        if not self._first(other):
            return
        log.error("node %s: another node of team %s joined under this robot's name%s, started %s: it leaves "
                  "the team and this node stays; %s", self.robot, self.team, self._at(other),
                  _started(started_at(other), started_at(self.incarnation), "after"), FIX)

    def clash(self, a: NameTaken) -> bool:
        """Another node runs under this robot's name: whether this one (of
        ``incarnation``, set as it started) leaves. Both say why."""
        self.trace.write("name_taken", "", self.robot, 0,
                         f"{'this node leaves' if a.leave else 'the other leaves'}: incarnation {a.other:x}")
        if not a.leave:
            self._stays(a.other)
            return False
        self.taken = (f"robot name {self.robot!r} is taken in team {self.team!r} by another node{self._at(a.other)}, "
                      f"started {_started(started_at(a.other), started_at(self.incarnation), 'before')}; {FIX}")
        log.error("node %s: %s; this node started later and leaves the team", self.robot, self.taken)
        return True
