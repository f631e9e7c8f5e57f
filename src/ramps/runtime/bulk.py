"""Large messages to teammates, sent whole and in order, off the driver's thread.

How this works: a node publishes to its teammates with Zenoh's DROP
congestion control, so that a frozen or cut-off teammate never stalls the
node's single driver thread; the core survives lost messages. That is right
for small messages and wrong for large ones. Zenoh queues two batches of 64 KB
per link and drops a message whose fragments wait more than 50 ms for room,
so with DROP a program's parameters (up to 1 MB) are lost whenever the link
cannot take them at once: on a 1 MB/s link every time, and on a fast link
whenever the sending node is short of CPU for a moment. On the testbed that
made the origin's offer time out on a slowed teammate and then on a
full-speed one, and the program run on the busy origin, 8 times longer.

So a message larger than ``LARGE`` goes to a sender thread of its own
destination, which publishes it with BLOCK congestion control (it waits for
room, and Zenoh closes a link that takes none for 5 s). Messages to the same
teammate that follow it while it is on its way queue behind it and keep
their order; messages to other teammates, and every small message to a
teammate with nothing queued, are published at once by the driver with
DROP. A destination holds at most ``MAX_QUEUED`` bytes: beyond that a
message is dropped (as DROP would drop it), and logged. A message may come
with ``on_way``: called with False when it is queued (before its thread can
be through with it) and with True once its thread is (sent or failed), so
the core's connect timeout of an offer counts from its last byte out
(``ramps.core.silence``).
"""

from __future__ import annotations

import logging
import threading
from collections import deque
from collections.abc import Callable

log = logging.getLogger("ramps.node")

#: messages above this many bytes are fragmented by Zenoh (one batch is 64 KB)
LARGE = 60 * 1024
#: bytes at most waiting for one destination
MAX_QUEUED = 64 * 1024 * 1024

#: put(key, data, block): publish, blocking for room when ``block``
Put = Callable[[str, bytes, bool], None]
#: on_way(done): a queued message's sending began (False) or is over (True)
OnWay = Callable[[bool], None]


class OrderedSender:
    """Per destination key: large messages sent whole by a thread, in order."""

    def __init__(self, put: Put, *, large: int = LARGE, max_queued: int = MAX_QUEUED, name: str = "") -> None:
        self._put = put
        self.large = large
        self.max_queued = max_queued
        self._name = name
        self._lock = threading.Lock()
        #: key -> messages waiting, and their bytes; a key is here while its thread runs
        self._queues: dict[str, deque[tuple[bytes, OnWay | None]]] = {}
        self._bytes: dict[str, int] = {}
        self.sent_whole = 0
        self.dropped = 0

    def send(self, key: str, data: bytes, on_way: OnWay | None = None) -> bool:
        """Queue ``data`` for ``key`` if it is large or follows a large one
        still on its way (``on_way(False)`` then, and ``on_way(True)`` once
        it is sent or failed); False: nothing queued, the caller publishes it now."""
        with self._lock:
            q = self._queues.get(key)
            if q is None:
                if len(data) <= self.large:
                    return False
                q = self._queues[key] = deque()
                self._bytes[key] = 0
                threading.Thread(target=self._drain, args=(key,), name=f"ramps-send-{self._name}",
                                 daemon=True).start()
            if self._bytes[key] + len(data) > self.max_queued:
                self.dropped += 1
                log.warning("node %s: %d bytes for %s dropped: %d bytes already wait for that link", self._name,
                            len(data), key, self._bytes[key])
                return True
            if on_way is not None:  # under the lock: before its thread can be through with it
                on_way(False)
            q.append((data, on_way))
            self._bytes[key] += len(data)
            return True

    def waiting(self, key: str) -> int:
        """Bytes queued for ``key`` (0 when nothing waits)."""
        with self._lock:
            return self._bytes.get(key, 0)

    def _drain(self, key: str) -> None:
        while True:
            with self._lock:
                q = self._queues[key]
                if not q:
                    del self._queues[key], self._bytes[key]
                    return
                data, on_way = q[0]
            try:
                self._put(key, data, len(data) > self.large)
                if len(data) > self.large:
                    self.sent_whole += 1
            except Exception as exc:  # a closed session or link: the core resends what matters
                log.warning("node %s could not send %d bytes on %s: %s", self._name, len(data), key, exc)
            if on_way is not None:
                on_way(True)
            with self._lock:
                q.popleft()
                self._bytes[key] -= len(data)
