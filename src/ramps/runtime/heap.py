"""Give the heap back after a burst of large messages (a flood, big results).

How this works: a node's transport callback turns every message into a
Python ``bytes`` object; under a flood of 1-9 MB messages the driver's
backlog holds up to ``MAX_BACKLOG_BYTES`` of them, and Zenoh and the
decoder hold a few more in flight. The node already makes every block over
256 KiB its own mapping, unmapped when freed (``node.return_freed_memory``),
yet glibc's heap kept 30-60 MB after ``ramps bench flood`` (the node's
private memory, measured, for as long as it ran; presumably the thousands
of smaller messages and their objects queued behind the big ones), so a
robot that weathered one flood would carry its high-water mark for good.
``HeapTrimmer`` counts the bytes that arrive (``note``, from the callback)
and, when at least ``threshold`` bytes came in since the last trim, asks
glibc to return free memory to the system (``malloc_trim(0)``) from the
driver's thread (``maybe_trim``, called once per load report). It costs
0.5-30 ms measured, so it runs at most once per report period and only
after that much traffic: small messages alone reach 16 MiB in hours.

Rules: where there is no glibc (musl, macOS), ``trim`` is None and nothing
happens. The trim function is injected for tests.
"""

from __future__ import annotations

import ctypes
import ctypes.util
from typing import Callable

#: bytes received between two trims, at least
TRIM_AFTER_BYTES = 16 * 1024 * 1024


def _glibc_trim() -> Callable[[], object] | None:
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        fn = libc.malloc_trim
    except (OSError, AttributeError):
        return None
    fn.argtypes = [ctypes.c_size_t]
    fn.restype = ctypes.c_int
    return lambda: fn(0)


class HeapTrimmer:
    """Counts received bytes; trims the heap once enough went through."""

    def __init__(self, threshold: int = TRIM_AFTER_BYTES, trim: Callable[[], object] | None = None,
                 *, use_glibc: bool = True) -> None:
        self.threshold = threshold
        self.trim = trim if trim is not None or not use_glibc else _glibc_trim()
        self.received = 0  # bytes since the last trim (written by the transport callback)
        self.trims = 0

    def note(self, size: int) -> None:
        self.received += size

    def maybe_trim(self, backlog_bytes: int = 0) -> bool:
        """Trim if ``threshold`` bytes arrived since the last trim and the
        backlog has drained (while it holds messages, their memory is in use)."""
        if self.trim is None or self.received < self.threshold or backlog_bytes > 0:
            return False
        self.received = 0
        self.trim()
        self.trims += 1
        return True


__all__ = ["TRIM_AFTER_BYTES", "HeapTrimmer"]
