"""A fleet's heartbeats, delivered in batches.

How this works: in a team of more robots than ``placement_sample`` (a
fleet), most of the simulator's events are heartbeats: every host's, each
period, to each origin of a program it runs, robots x origins events a
period. Here each goes into its receiver's mailbox instead, due when it
would have arrived (the link's latency and its size over the bandwidth; it
does not wait behind the link's queue), and each receiver empties its
mailbox once per ``GRID`` seconds of virtual time, at the first grid instant
at or after a heartbeat is due: one event and one ``Node.handle_all`` for
all that reached it since. A newer heartbeat from the same host replaces
an older one still waiting (it lists the programs running there now). A
heartbeat whose host's links broke (crash, cut, freeze) before it was read,
or whose receiver's did, is lost, as one in flight on a link is.

What it changes: a heartbeat reaches its origin up to ``GRID`` later than
on its own (a tenth of the 2 s a silent host has before it is written
off, by default), in one batch; nothing else. Teams of at most
``placement_sample`` robots never use it: they run exactly as without it.
Load reports do not go by mailbox: an origin that hears a host's report of
the instant later places more programs on stale figures (500 robots, 10
origins: offers turned away 611 -> 2,789, makespan 1.054 -> 1.143x the
capacity bound with reports by mailbox too; docs/lab/2026-11-27-sim-scale-3.md).

Rules: the simulator's; decisions stay in the node (``ramps.core``).
"""

from __future__ import annotations

import math
import random
from typing import Any, Callable, Protocol

from ramps.core.events import Action, Received
from ramps.core.messages import Heartbeat, Message
from ramps.sim.scenario import NetworkSpec
from ramps.sim.wire import wire_size


class _Robot(Protocol):
    """What a mailbox reads of ``ramps.sim.engine._Robot``."""

    spec: Any
    node: Any
    epoch: int

    @property
    def reachable(self) -> bool: ...


class _Sim(Protocol):
    """What a mailbox reads and calls of ``ramps.sim.engine.Simulator``."""

    now: float
    sent: int
    dropped: int
    net: NetworkSpec
    rng: random.Random
    robots: dict[str, Any]
    _links: dict[tuple[str, str], list[float]]

    def _at(self, t: float, fn: Callable[..., None], arg: Any = None) -> None: ...
    def _link(self, src: Any, dst: Any) -> list[float]: ...
    def _apply(self, r: Any, actions: list[Action]) -> None: ...


#: seconds of virtual time between two readings of a fleet robot's mailbox
GRID = 0.2

_Waiting = tuple[_Robot, int, _Robot, int, Message]


class Mailboxes:
    """Every fleet robot's mailbox: (receiver, grid step) -> sending host -> what waits."""

    def __init__(self, sim: _Sim) -> None:
        self.sim = sim
        self._boxes: dict[tuple[str, int], dict[str, _Waiting]] = {}
        #: messages read, and lost with a link that broke while they waited; mailboxes read
        self.read = self.lost = self.batches = 0

    def beat(self, src: _Robot, to: str, msg: Heartbeat) -> None:
        """A host's heartbeat to ``to``, sent now (outside the link's queue)."""
        sim = self.sim
        sim.sent += 1
        dst = sim.robots.get(to)
        if dst is None or not src.reachable or not dst.reachable or (sim.net.loss and sim.rng.random() < sim.net.loss):
            sim.dropped += 1
            return
        link = sim._links.get((src.spec.name, to)) or sim._link(src, dst)
        self.post(src, dst, msg, sim.now + link[1] + wire_size(msg) / link[2])

    def post(self, src: _Robot, dst: _Robot, msg: Message, due: float) -> None:
        """``msg`` from ``src`` reaches ``dst`` at ``due``: read at the grid instant then or after."""
        step = math.ceil(due / GRID)
        key = (dst.spec.name, step)
        box = self._boxes.get(key)
        if box is None:
            box = self._boxes[key] = {}
            self.sim._at(step * GRID, self._read, key)
        box[src.spec.name] = (src, src.epoch, dst, dst.epoch, msg)

    def _read(self, key: tuple[str, int]) -> None:
        box = self._boxes.pop(key)
        self.batches += 1
        events = []
        dst = None
        for src, se, to, de, msg in box.values():
            if se != src.epoch or de != to.epoch or not to.reachable:
                self.lost += 1
                continue
            dst = to
            events.append(Received(sender=src.spec.name, msg=msg))
        if dst is not None:
            self.read += len(events)
            self.sim._apply(dst, dst.node.handle_all(events, self.sim.now))
