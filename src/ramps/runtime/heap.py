"""Give the heap back after a burst of large messages (a flood, big results).

How this works: a node's transport callback turns every message into a
Python ``bytes`` object; under a flood of 1-9 MB messages the driver's
backlog holds up to ``MAX_BACKLOG_BYTES`` of them, and Zenoh and the
decoder hold a few more in flight. The node makes every block over
256 KiB its own mapping, unmapped when freed (``return_freed_memory``, at
start), yet glibc's heap kept 30-60 MB after ``ramps bench flood`` (the node's
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



def return_freed_memory(threshold: int = 256 * 1024) -> None:
    """Make glibc hand large freed blocks back to the system at once.

    By default glibc raises its mmap threshold each time a large block is
    freed (up to 32 MiB), so later multi-megabyte messages are carved from the
    heap and stay resident after they are dropped: a flood with 1-9 MB garbage
    left a node 36-50 MB bigger (``ramps bench flood``), 1-22 MB with this. A
    fixed threshold keeps every block over ``threshold`` bytes (Python's and
    Zenoh's) in its own mapping, unmapped when freed. Other C libraries: no-op."""
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):
        return
    m_mmap_threshold = -3  # glibc's M_MMAP_THRESHOLD
    mallopt(ctypes.c_int(m_mmap_threshold), ctypes.c_int(threshold))


__all__ = ["TRIM_AFTER_BYTES", "HeapTrimmer", "return_freed_memory"]
