"""What a node makes of the bytes it receives: a message, or a drop that is counted.

How this works: ``WireIntake`` is a part of the node's driver
(``ramps.runtime.node``). The bytes a transport callback hands the driver
are queued only if the driver's backlog has room for them (``admit``: a
flood, or a driver that cannot keep up, is dropped and counted,
``overflow``, so memory stays bounded). ``decode`` takes the bytes of a
queued message out of the backlog and turns them into its envelope, or
counts it dropped (``bad``; ``ramps status`` shows both counts): a
malformed message is logged one line a ``DROP_LOG_PERIOD``, with how many
went unlogged since; a message of another major protocol version is
refused and a message type of a newer minor skipped, each counted apart
too (``version_refused``, ``unknown_types``) and logged naming the sender
and the version or type the first time (``VERSION_LOG_KEYS`` pairs at most:
a hostile sender inventing names is only counted). Other remote bad input
the driver finds (``refused``) counts the same.

Teammates' periodic load reports do not wake the driver: they wait in
``later`` for its next round, which takes them before anything else. So do
heartbeats, acceptances, progress and results' acknowledgements
(``ramps.core.wirepeek.can_wait``; a heartbeat's silence counts from its
arrival, ``Received.at``). A round comes at least every report period (a
report is then read up to that late, within the period it stands for), so
an origin hearing a hundred teammates runs a round for many of their
messages instead of one each. Everything else wakes it: reports of the
instant, offers, refusals and results.
"""

from __future__ import annotations

import logging
from collections import deque
from typing import Any

from ramps.core.messages import Envelope, UnknownMessageType, VersionRefused, WireError, decode

log = logging.getLogger("ramps.node")
#: seconds between two log lines about dropped messages (each is counted)
DROP_LOG_PERIOD = 1.0
#: (robot, version) pairs of refused versions and unknown types, each logged
#: once; more than this (a hostile sender inventing names) are only counted
VERSION_LOG_KEYS = 64


class WireIntake:
    """The messages robot ``robot``'s node receives, decoded or counted as dropped."""

    def __init__(self, robot: str) -> None:
        self.robot = robot
        #: messages dropped as bad input, of them those refused as another major
        #: protocol version and those skipped as a message type of a newer minor
        #: (docs/wire-compatibility.md): logged as such, not as malformed
        self.bad = 0
        self.version_refused = 0
        self.unknown_types = 0
        self._version_logged: frozenset[tuple[str, str]] = frozenset()
        #: a flood of bad messages is logged one line per DROP_LOG_PERIOD
        self._logged_at = -DROP_LOG_PERIOD
        self._unlogged = 0
        #: bytes queued for the driver and not decoded yet, and the messages
        #: dropped because they did not fit
        self.backlog = 0
        self.overflow = 0
        #: teammates' periodic reports and messages that can wait, admitted, for the driver's next round
        self.later: deque[tuple[Any, ...]] = deque()

    def admit(self, size: int, limit: int) -> bool:
        """Whether a message of ``size`` bytes fits in a backlog of ``limit``
        bytes (it is then in it); if not, it is dropped and counted."""
        if self.backlog + size > limit:
            self.overflow += 1
            return False
        self.backlog += size
        return True

    def decode(self, data: bytes, now: float) -> Envelope | None:
        """The message in ``data`` at the core's time ``now`` (the wire
        limit; client arguments are checked on submit), or None: dropped.
        Its bytes leave the backlog."""
        self.backlog -= len(data)
        try:
            return decode(data)
        except VersionRefused as exc:
            self.bad += 1  # dropped (`ramps status`), but not logged as malformed
            self.version_refused += 1
            self._log_version(exc.sender, f"protocol {exc.speaks}",
                              f"node {self.robot} refuses the messages of {exc.sender or 'a robot'!r}: {exc}; "
                              f"run one major protocol version in a team")
        except UnknownMessageType as exc:
            self.bad += 1
            self.unknown_types += 1
            self._log_version(exc.sender, exc.tag, f"node {self.robot} skipped a message: {exc}")
        except WireError as exc:
            self.bad += 1
            if now - self._logged_at < DROP_LOG_PERIOD:
                self._unlogged += 1
            else:
                n = self._unlogged
                more = f" ({n} more dropped since the last such line)" if n else ""
                log.warning("node %s dropped a message: %s%s", self.robot, exc, more)
                self._logged_at, self._unlogged = now, 0
        return None

    def refused(self, what: str, exc: Exception | None, now: float) -> None:
        """Other bad input from the team, dropped: counted, and ``what`` is
        logged with ``exc`` (if any) at most one line a period."""
        self.bad += 1
        if exc is not None and now - self._logged_at >= DROP_LOG_PERIOD:  # a flood is one line a period
            log.warning("node %s ignored %s: %s", self.robot, what, exc)
            self._logged_at = now

    def _log_version(self, sender: str, what: str, line: str) -> None:
        """Log a refused version or an unknown type the first time a robot sends it."""
        key = (sender, what)
        if key in self._version_logged or len(self._version_logged) >= VERSION_LOG_KEYS:
            return
        self._version_logged = self._version_logged | {key}
        log.warning("%s", line)
