"""A node's place on its team's transport: what it subscribes to and declares.

How this works: ``Membership`` is a part of the node's driver
(``ramps.runtime.node``). Once the driver has opened its transport, ``join``
subscribes to this robot's inbox and the team's load reports (periodic and
of the instant), to the team's liveliness tokens and, on a secured team, to
its revocation lists; declares the publishers of this robot's load reports,
its liveliness token and its ``where`` token (where it listens, by
incarnation: ``keys.where``, read by a node that meets it under its own
name). Every callback only queues an item for the driver. ``say_leaving``
declares the token that tells a client a node leaving from one that crashed;
``leave`` undeclares the rest and closes the transport.
"""

from __future__ import annotations

import logging
from typing import Any, Callable

from ramps.runtime import keys, revocation
from ramps.runtime.transport import Declared, Publisher, Transport

log = logging.getLogger("ramps.node")


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
