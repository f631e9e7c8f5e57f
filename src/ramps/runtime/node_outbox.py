"""How a node publishes: declared publishers, a message dropped rather than block, large ones apart.

How this works: ``Outbox`` is a part of the node's driver
(``ramps.runtime.node``); it publishes on whatever transport the driver has
now (none: nothing goes). Messages to robots use Zenoh's DROP congestion
control: a frozen teammate must never stall the node's only driver thread,
and the core already survives lost messages (connect timeouts, periodic
heartbeats, results resent until acknowledged). Outcomes to a client
(``block=True``) are not resent, so they wait. A message to a teammate over
``bulk.LARGE`` (or behind one) goes whole, in order, on a thread of its
destination (``send``; ``ramps.runtime.bulk``). Publishers are declared on
first use and the newest 4096 kept, the oldest undeclared: clients come and
go.
"""

from __future__ import annotations

import logging
from typing import Callable

from ramps.runtime.bulk import OnWay, OrderedSender
from ramps.runtime.transport import Publisher, Transport

log = logging.getLogger("ramps.node")
#: declared publishers kept per table
PUBLISHERS_KEPT = 4096


class Outbox:
    """Robot ``robot``'s node's publishing on ``transport()`` (None: not joined, or gone)."""

    def __init__(self, robot: str, transport: Callable[[], Transport | None]) -> None:
        self.robot = robot
        self._transport = transport
        #: the declared publishers of messages and outcomes, by key
        self.pubs: dict[str, Publisher] = {}
        #: large messages to teammates: sent whole, in order, off the driver's thread
        self._bulk = OrderedSender(self._bulk_put, name=robot)

    def connected(self) -> bool:
        return self._transport() is not None

    def send(self, key: str, data: bytes, on_way: OnWay | None = None) -> None:
        """A message to a teammate: at once, or by its destination's thread if
        large (or behind a large one; ``on_way``: see ``OrderedSender.send``)."""
        if not self._bulk.send(key, data, on_way):
            self.put(key, data)

    def put(self, key: str, data: bytes, *, block: bool = False) -> None:
        """Publish on ``key`` (``block``: wait for room rather than drop); a failure is logged."""
        if self._transport() is None:
            return
        try:
            (self.pubs.get(key) or self.publisher(key, block)).put(data)
        except Exception as exc:
            log.warning("node %s could not publish on %s: %s", self.robot, key, exc)

    def reachable(self, key: str, block: bool) -> bool:
        """Whether a subscriber matches ``key`` now (True when it cannot tell)."""
        if self._transport() is None:
            return True
        try:
            return bool(self.publisher(key, block).matching())
        except Exception:  # cannot tell: send
            return True

    def publisher(self, key: str, block: bool, pubs: dict[str, Publisher] | None = None) -> Publisher:
        """The declared publisher of ``key`` from ``pubs`` (default: those of
        messages and outcomes; a client's advisory updates have their own, as
        they never block). Needs a transport; raises what it raises."""
        pubs = self.pubs if pubs is None else pubs
        pub = pubs.get(key)
        if pub is None:
            transport = self._transport()
            assert transport is not None
            pub = pubs[key] = transport.publisher(key, block=block)
            if len(pubs) > PUBLISHERS_KEPT:
                pubs.pop(next(iter(pubs))).undeclare()
        return pub

    def _bulk_put(self, key: str, data: bytes, block: bool) -> None:
        """The sender thread's publish (``ramps.runtime.bulk``): a large message
        waits for room on the link instead of being dropped."""
        transport = self._transport()
        if transport is not None:
            transport.put(key, data, block=block)
