"""Which messages a node may read at its next round, told from their bytes without decoding.

How this works: a node's driver wakes for each message it receives, and a
round costs far more than reading one message in it. Some messages change
nothing the node does before its timers fire, and each round reads the held
ones before it fires any: a host's heartbeats (an origin watching 40 hosts
hears 80 a second), its acceptance of an offer, an origin's acknowledgement
of a result, a program's progress. ``can_wait`` tells them by the type tag
at the head of the envelope, ``{"v": major, "sender": name, "msg":
{"type": tag, ...}}`` in that order (``ramps.core.messages.encode``). A
guess that is wrong either way changes only when a message is read: another
encoding of the head (a map of more than 15 fields, a newer major) is read
at once.

Rules: pure functions of bytes; no decoding, no I/O.
"""

from __future__ import annotations

import msgspec

from ramps.core.wirebase import PROTOCOL_MAJOR

_HEAD = b"\x83" + msgspec.msgpack.encode("v") + msgspec.msgpack.encode(PROTOCOL_MAJOR) + msgspec.msgpack.encode("sender")
_MSG, _TYPE = msgspec.msgpack.encode("msg"), msgspec.msgpack.encode("type")
#: the tags of the messages that may wait (``ramps.core.messages``)
WAIT_TAGS = ("heartbeat", "accept", "ack", "progress")
_WAIT = tuple(msgspec.msgpack.encode(t) for t in WAIT_TAGS)


def can_wait(data: bytes) -> bool:
    """Whether ``data`` is an envelope of one of ``WAIT_TAGS``' messages, by its head alone."""
    if not data.startswith(_HEAD) or len(data) < len(_HEAD) + 3:
        return False
    i = len(_HEAD)
    b = data[i]
    if 0xA0 <= b <= 0xBF:  # the sender's name: a fixstr, str 8 or str 16
        i += 1 + b - 0xA0
    elif b == 0xD9:
        i += 2 + data[i + 1]
    elif b == 0xDA:
        i += 3 + int.from_bytes(data[i + 1:i + 3], "big")
    else:
        return False
    if not data.startswith(_MSG, i) or len(data) <= i + len(_MSG) or not 0x80 <= data[i + len(_MSG)] <= 0x8F:
        return False
    i += len(_MSG) + 1  # past a fixmap's header
    return data.startswith(_TYPE, i) and data.startswith(_WAIT, i + len(_TYPE))
