"""The robots a secured team revoked, as one node knows them.

How this works: ``Revoked`` is a part of the node's driver
(``ramps.runtime.node``). On a secured team, at start, ``load`` reads the
list saved beside this robot's credentials (a robot on it does not join:
``NotAdmitted``) and keeps the team CA that signs lists. A list from the
team (``adopt``) is taken if it is newer and signed by that CA: it is saved,
passed on at once and then every ``revocation.REPUBLISH_PERIOD``
(``republish``), and the robots it newly names are returned, for the driver
to shut them out; this robot among them means it must leave (``me``).
Messages from a revoked robot are dropped and counted (``shuts_out``). On a
team that is not secured, none of this runs (``secured`` is false).
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING

from ramps.errors import NotAdmitted
from ramps.runtime import revocation

if TYPE_CHECKING:
    from cryptography import x509

    from ramps.runtime.credentials import Credentials
    from ramps.runtime.revocation import RevocationList

log = logging.getLogger("ramps.node")


class Revoked:
    """The revocation list robot ``robot``'s node holds for team ``team``."""

    def __init__(self, team: str, robot: str) -> None:
        self.team = team
        self.robot = robot
        #: the newest list, and the robots it names
        self.current: RevocationList | None = None
        self.robots: frozenset[str] = frozenset()
        #: the team CA that signs lists (None: the team is not secured), and where the list is saved
        self._ca_cert: x509.Certificate | None = None
        self._file: str | None = None
        self._republish_at = 0.0
        #: messages dropped because their sender is revoked; this robot itself was revoked
        self.dropped = 0
        self.me = False

    @property
    def secured(self) -> bool:
        """Whether lists are watched for (a secured team, after ``load``)."""
        return self._ca_cert is not None

    def load(self, creds: Credentials) -> None:
        """Secured team: the list saved beside this robot's credentials, if
        any. A robot on it does not join (``NotAdmitted``)."""
        from ramps.runtime.security import _load_cert

        self._ca_cert = _load_cert(creds.ca, "team CA certificate")
        self._file = str(creds.cert.parent / revocation.REVOKED_FILE)
        rl = revocation.load(self._file, self._ca_cert, self.team)
        if rl is None:
            return
        if self.robot in rl.robots:
            raise NotAdmitted(f"robot {self.robot!r} is revoked by team {self.team!r} (revocation list {rl.seq} "
                              f"of {rl.issued}, {self._file}): it may not join the team")
        self.current, self.robots = rl, frozenset(rl.robots)

    def shuts_out(self, sender: str) -> bool:
        """Whether a message from ``sender`` is dropped (and counted): it is revoked."""
        if sender in self.robots:
            self.dropped += 1
            return True
        return False

    def adopt(self, data: bytes) -> list[str] | None:
        """A list from the team: the robots it newly revokes, sorted (None if
        it is not newer than this node's). Raises what ``revocation.decode``
        raises on a list that is malformed, of another team or not signed by
        the team CA (remote bad input)."""
        assert self._ca_cert is not None and self._file is not None
        rl = revocation.decode(data, self._ca_cert, self.team)
        if self.current is not None and rl.seq <= self.current.seq:
            return None
        new = sorted(set(rl.robots) - self.robots)
        self.current, self.robots = rl, frozenset(rl.robots)
        self._republish_at = 0.0  # pass it on now
        try:
            revocation.save(self._file, rl)
        except OSError as exc:
            log.warning("node %s could not save revocation list %d to %s: %s", self.robot, rl.seq, self._file, exc)
        if self.robot in new:
            self.me = True
        return new

    def republish(self, now: float) -> bytes | None:
        """The list to publish again at the core's time ``now``, if it is due (None: not now)."""
        if self.current is None or now < self._republish_at:
            return None
        self._republish_at = now + revocation.REPUBLISH_PERIOD
        return revocation.encode(self.current)
