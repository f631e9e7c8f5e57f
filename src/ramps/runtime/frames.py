"""Frames between the worker pool, the fork server and the workers.

How this works: a frame is a 4-byte big-endian length and a body (msgpack:
``ramps.runtime.worker`` lists what travels each way); ``read_frame`` reads
one back whole, however the pipe cuts it.

Rules: nothing is pickled; ``read_frame`` returns None at the end of a
stream or on a frame cut short by it.
"""

from __future__ import annotations

import struct
from typing import BinaryIO

_LEN = struct.Struct(">I")


def _read_exactly(stream: BinaryIO, n: int) -> bytes:
    """``n`` bytes, or fewer at end of stream. The pipes of forked workers are
    unbuffered (``buffering=0``), where one ``read`` returns at most what the
    pipe holds (64 KiB), so a frame beyond that takes several reads."""
    data = stream.read(n)
    if data is None or len(data) == n:
        return data or b""
    parts = [data]
    got = len(data)
    while got < n:
        more = stream.read(n - got)
        if not more:
            break
        parts.append(more)
        got += len(more)
    return b"".join(parts)


def read_frame(stream: BinaryIO) -> bytes | None:
    head = _read_exactly(stream, 4)
    if len(head) < 4:
        return None
    (n,) = _LEN.unpack(head)
    body = _read_exactly(stream, n)
    return body if len(body) == n else None


def frame(body: bytes) -> bytes:
    return _LEN.pack(len(body)) + body
