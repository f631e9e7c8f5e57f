"""A node's place on its team's transport: what it subscribes to and declares.

How this works: before a node joins, ``join_checks`` checks its
credentials on a secured team (and whether the teammates it connects to
admit them) or warns, once per process, that the team is not secured.
``Membership`` is a part of the node's driver
(``ramps.runtime.node``). Once the driver has opened its transport, ``join``
subscribes to this robot's inbox and the team's load reports (periodic and
of the instant), to the team's liveliness tokens, to the tokens of the
applications that submit through this node (``keys.app``: it is an origin
before their first program) and, on a secured team, to its revocation lists; declares the publishers of this robot's load reports,
its liveliness token and its ``where`` token (where it listens, by
incarnation: ``keys.where``, read by a node that meets it under its own
name). Every callback only queues an item for the driver. ``say_leaving``
declares the token that tells a client a node leaving from one that crashed;
``leave`` undeclares the rest and closes the transport.
"""

from __future__ import annotations

import logging
from typing import TYPE_CHECKING, Any, Callable

from ramps.runtime import keys, revocation
from ramps.runtime.security import admission, settings_credentials
from ramps.runtime.transport import Declared, Publisher, Transport

if TYPE_CHECKING:
    from ramps.runtime.credentials import Credentials
    from ramps.runtime.settings import NodeSettings

log = logging.getLogger("ramps.node")
#: what a node of a team that is not secured says, once per process
INSECURE_WARNING = (
    "INSECURE: team {team!r} runs without authentication or encryption: anyone who can reach this network "
    "can join it, read its traffic, submit programs and run them on this robot. To secure it: "
    "`ramps team init`, `ramps team add ROBOT`, then `ramps node --secure --credentials DIR` (README, Security).")
_insecure_warned = False


class Membership:
    """Robot ``robot``'s node on team ``team``, off until ``join``."""

    #: this robot's load reports: the periodic ones and those of the instant (``keys.load_now``)
    load_pub: Publisher
    prompt_pub: Publisher

    def __init__(self, team: str, robot: str) -> None:
        self.team = team
        self.robot = robot
        self._subs: list[Declared] = []
        #: its liveliness and ``where`` tokens (undeclared when it leaves), its leaving token (kept)
        self._tokens: list[Declared] = []
        self._leaving: Declared | None = None

    def join(self, t: Transport, incarnation: int, *, on_wire: Callable[[bytes], None],
             put: Callable[[tuple[Any, ...]], None], on_where: Callable[[str, bool], None],
             revocations: bool) -> None:
        """Subscribe and declare on ``t``: messages and reports go to
        ``on_wire``, liveliness (and revocation lists, if ``revocations``) to
        the driver's queue through ``put``, ``where`` tokens to ``on_where``.
        Raises what the transport raises (the driver then leaves)."""
        team, robot = self.team, self.robot
        self._subs = [
            t.subscribe(keys.inbox(team, robot), on_wire),
            t.subscribe(keys.load(team), on_wire),
            t.subscribe(keys.load_now(team), on_wire),
            t.subscribe_liveliness(keys.alive(team), lambda key, alive: put(("live", keys.robot_of(key), alive)),
                                   history=True),
        ]
        if revocations:
            self._subs.append(t.subscribe(revocation.revoked_key(team), lambda data: put(("revoked", data))))
        self.load_pub = t.publisher(keys.load(team, robot))
        self.prompt_pub = t.publisher(keys.load_now(team, robot))
        self._tokens.append(t.declare_token(keys.alive(team, robot)))
        self._subs.append(t.subscribe_liveliness(keys.app(team, robot), lambda key, here: put(("app", here)),
                                                 history=True))
        self._subs.append(t.subscribe_liveliness(keys.where(team, robot), on_where, history=True))
        self._tokens.append(t.declare_token(keys.where(team, robot, incarnation, t.locators())))

    def say_leaving(self, t: Transport) -> None:
        """Declare that this node leaves, before its liveliness goes: a client
        (``ramps top``) tells this from a crash."""
        try:
            self._leaving = t.declare_token(keys.leaving(self.team, self.robot))
        except Exception as exc:
            log.warning("node %s could not say it is leaving: %s", self.robot, exc)

    def leave(self, t: Transport | None) -> None:
        """Undeclare the tokens, then the subscriptions, then close ``t`` (if any)."""
        for declared in self._tokens + self._subs:
            try:
                declared.undeclare()
            except Exception:
                pass
        self._tokens, self._subs = [], []
        if t is not None:
            try:
                t.close()
            except Exception:
                pass


def join_checks(s: NodeSettings) -> tuple[Credentials | None, bool]:
    """Before a node of settings ``s`` joins. Secure mode: its robot's
    checked credentials, and whether Zenoh may fail fast (every connect
    endpoint admitted them; see ``security.admission``, which raises
    ``NotAdmitted`` when the team refuses them). Insecure mode: say so, once
    per process."""
    global _insecure_warned
    if not s.secure:
        if not _insecure_warned:
            _insecure_warned = True
            log.warning(INSECURE_WARNING.format(team=s.team))
        return None, False
    creds = settings_credentials(s, robot=s.robot)
    everyone = admission(s.connect, creds, team=s.team)
    if s.connect and not everyone:
        log.info("node %s: not every teammate at %s answers yet; Zenoh keeps trying", s.robot,
                 ", ".join(s.connect))
    return creds, everyone
