"""The protocol's version, its errors, and the base of every wire record.

How this works: ``ramps.core.messages`` defines the records and decodes
them, and re-exports everything here; this module holds what every record
module needs before any record exists (``Record``) and what a receiver
raises for bytes it cannot take (``WireError`` and its two kinds that are
not malformed: another major, an unknown type), with the helpers that
word those errors.
"""

from __future__ import annotations

from typing import Annotated, TypeVar

import msgspec
from msgspec import Meta

from ramps.core.wirelimits import RobotName
from ramps.version import __version__

#: the protocol this code speaks, major.minor. 1.0 is ramps 0.1.0 (strict: it refuses unknown fields
#: and types); 1.1 (ramps 0.2.0) decodes tolerantly and adds optional fields, left out at their defaults
#: (docs/wire-compatibility.md): ``ProgramResult.worker_died`` (a program killed its own worker); with
#: a deadline, ``OffloadRequest.deadline_in``, ``SubmitProgram.deadline``, ``SubmitProgram.on_miss``,
#: ``ProgramOutcome.missed_deadline``; with a battery, ``LoadReport.battery``, ``LoadReport.low_battery``,
#: ``LoadReport.power``; with accelerators, ``LoadReport.accelerators`` (``AcceleratorSeen``),
#: ``OffloadRequest.accelerator``, ``SubmitProgram.accelerator``, ``SubmitProgram.accelerator_work``,
#: ``SubmitProgram.cpu_fallback``; from robots that measure their own speed, in reports of the
#: instant only, ``LoadReport.speed_class`` and ``LoadReport.cpu_rate``; from robots whose application
#: submits, in reports of the instant only, ``LoadReport.submits``, and one new type, ``BurstClaim``.
#: The envelope's ``v`` is the major only (1.0 checks ``v == 1``).
PROTOCOL_MAJOR = 1
PROTOCOL_MINOR = 1
#: the envelope's ``v`` (kept under its old name for the fuzzers and tests)
PROTOCOL_VERSION = PROTOCOL_MAJOR
#: what this node says it speaks, e.g. "1.1"
PROTOCOL = f"{PROTOCOL_MAJOR}.{PROTOCOL_MINOR}"


class WireError(ValueError):
    """Bytes from the network that are not a valid message of this protocol."""


class VersionRefused(WireError):
    """A message of another major protocol version: not malformed, not
    understood. ``version`` is its major, ``minor`` and ``release`` what its
    envelope said of itself (a node of major 2 or later may say it), and
    ``sender`` the robot it claims to come from (unchecked; "" if unusable)."""

    def __init__(self, text: str, *, version: int, minor: int | None, release: str, sender: str) -> None:
        super().__init__(text)
        self.version, self.minor, self.release, self.sender = version, minor, release, sender

    @property
    def speaks(self) -> str:
        """The other node's protocol, as far as its message says: "2" or "2.3"."""
        return f"{self.version}" if self.minor is None else f"{self.version}.{self.minor}"


class UnknownMessageType(WireError):
    """A message of this major whose type this node does not know: a newer
    minor's addition, which by the policy an older node may skip."""

    def __init__(self, text: str, *, tag: str, sender: str) -> None:
        super().__init__(text)
        self.tag, self.sender = tag, sender


class Record(msgspec.Struct, frozen=True, kw_only=True, omit_defaults=True, tag_field="type"):
    """The base of every wire message: frozen, keyword-only, tagged by
    ``type``, fields at their defaults left out when encoded."""


class Head(msgspec.Struct):
    """What decode reads of an envelope it could not take whole: the major
    version, and for a message of another major whatever it says of its
    sender and itself (raw, so a future envelope of any shape still gets its
    version named)."""

    v: int
    sender: msgspec.Raw = msgspec.Raw(b"")
    minor: msgspec.Raw = msgspec.Raw(b"")
    release: msgspec.Raw = msgspec.Raw(b"")


head_decoder = msgspec.msgpack.Decoder(Head)
_name_decoder = msgspec.msgpack.Decoder(RobotName)
_minor_decoder = msgspec.msgpack.Decoder(Annotated[int, Meta(ge=0, lt=1 << 16)])
_release_decoder = msgspec.msgpack.Decoder(Annotated[str, Meta(max_length=32, pattern=r"\A[0-9A-Za-z.+-]*\Z")])
#: every way msgspec says "not this schema": its own errors, and two it lets
#: through (a string that is not UTF-8; absurdly deep nesting). Nothing else
#: may escape ``decode`` (tests/test_fuzz.py, ``ramps bench fuzz``)
DECODE_ERRORS = (msgspec.DecodeError, msgspec.ValidationError, UnicodeDecodeError, RecursionError)

_T = TypeVar("_T")


def _optional(decoder: msgspec.msgpack.Decoder[_T], raw: msgspec.Raw) -> _T | None:
    """What ``raw`` holds if the decoder accepts it, else None (absent, or not sane)."""
    if not len(raw):
        return None
    try:
        return decoder.decode(raw)
    except DECODE_ERRORS:
        return None


def refused(head: Head) -> VersionRefused:
    """The error for a message of another major, naming both versions."""
    sender = _optional(_name_decoder, head.sender) or ""
    minor = _optional(_minor_decoder, head.minor)
    release = _optional(_release_decoder, head.release) or ""
    speaks = f"{head.v}" if minor is None else f"{head.v}.{minor}"
    whose = f"sent by {sender!r}" if sender else "from a node that gave no usable name"
    rel = f" (ramps {release})" if release else ""
    return VersionRefused(
        f"protocol version mismatch: message is version {speaks}, {whose}{rel}; this node speaks version "
        f"{PROTOCOL} (ramps {__version__}); another major version is refused (docs/wire-compatibility.md)",
        version=head.v, minor=minor, release=release, sender=sender)


def why(exc: Exception) -> str:
    """What a decoding error says, in words."""
    if isinstance(exc, RecursionError):
        return "nested too deeply"
    if isinstance(exc, UnicodeDecodeError):
        return f"a string is not UTF-8 ({exc.reason})"
    return str(exc)
