"""The protocol's version, its errors, and the base of every wire record.

How this works: ``ramps.core.messages`` defines the records and decodes
them, and re-exports everything here; this module holds what every record
module needs before any record exists (``Record``) and what a receiver
raises for bytes it cannot take (``WireError`` and its two kinds that are
not malformed: another major, an unknown type).
"""

from __future__ import annotations

import msgspec

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
