"""A node's place on its team's transport: what it subscribes to and declares.

How this works: before a node joins, ``join_checks`` checks its
credentials on a secured team (and whether the teammates it connects to
admit them) or warns, once per process, that the team is not secured.
``Membership`` is a part of the node's driver
(``ramps.runtime.node``). Once the driver has opened its transport, ``join``
subscribes to this robot's inbox, to every report of the instant
(``keys.load_now``: they carry the speed class and who submits, and are
rare on an idle team), to the periodic reports under this robot's own name
only (its own, and another node's under its name: ``ramps.core.identity``),
to the team's liveliness tokens, to the tokens of the applications that
submit through this node (``keys.app``: it is an origin before their first
program) and, on a secured team, to its revocation lists; declares the
publishers of this robot's load reports, a queryable on its periodic
report's key that answers with its newest report (``newest``), its
liveliness token and its ``where`` token (where it listens, by
incarnation: ``keys.where``, read by a node that meets it under its own
name). Every callback only queues an item for the driver.

Report scope: only a robot that places programs (an origin) needs its
teammates' periodic reports, so an idle team's traffic per robot does not
grow with the team. ``widen`` (an application connected, or this robot has
a program to place) subscribes to every teammate's periodic reports, then
queries their newest ones once (``FETCH_TIMEOUT``) and queues ``("views",)``
when the query is over: until then the driver holds its clients' requests
(``ramps.runtime.node_inbound``), so an origin never places on an empty
view. An origin stays one. ``alive``: the teammates whose liveliness the
core was told of, which a robot that places nothing reports as those it
sees. ``say_leaving`` declares the token that tells a client a node
leaving from one that crashed; ``leave`` undeclares the rest and closes the
transport.
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
#: seconds an origin's query for its teammates' newest reports may take (a frozen teammate's
#: reply is not waited for longer: its next periodic report comes within a report period)
FETCH_TIMEOUT = 1.0


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
        #: the subscription to this robot's own name's periodic reports (until ``widen``)
        self._own: Declared | None = None
        self._on_wire: Callable[[bytes], None] = lambda data: None
        self._on_periodic: Callable[[bytes], None] = self._on_wire
        self._put: Callable[[tuple[Any, ...]], None] = lambda item: None
        #: this robot's newest load report as published (periodic or of the instant): the queryable's answer
        self.newest: bytes | None = None
        #: subscribed to every teammate's periodic reports; their newest fetched (or the query over)
        self.wide = self.ready = False
        #: teammates' reports the query brought
        self.fetched = 0
        #: teammates whose liveliness the core holds (``ramps.runtime.node_inbound``)
        self.alive: set[str] = set()

    def join(self, t: Transport, incarnation: int, *, on_wire: Callable[[bytes], None],
             put: Callable[[tuple[Any, ...]], None], on_where: Callable[[str, bool], None],
             revocations: bool, on_periodic: Callable[[bytes], None] | None = None) -> None:
        """Subscribe and declare on ``t``: messages and reports go to
        ``on_wire``, liveliness (and revocation lists, if ``revocations``) to
        the driver's queue through ``put``, ``where`` tokens to ``on_where``.
        Raises what the transport raises (the driver then leaves). Once it
        places programs (``widen``), every teammate's periodic reports go to
        ``on_periodic`` (default ``on_wire``)."""
        team, robot = self.team, self.robot
        self._on_wire, self._put = on_wire, put
        self._on_periodic = on_periodic or on_wire
        self._own = t.subscribe(keys.load(team, robot), on_wire)
        self._subs = [
            t.subscribe(keys.inbox(team, robot), on_wire),
            self._own,
            t.subscribe(keys.load_now(team), on_wire),
            t.subscribe_liveliness(keys.alive(team), lambda key, alive: put(("live", keys.robot_of(key), alive)),
                                   history=True),
        ]
        if revocations:
            self._subs.append(t.subscribe(revocation.revoked_key(team), lambda data: put(("revoked", data))))
        self.load_pub = t.publisher(keys.load(team, robot))
        self.prompt_pub = t.publisher(keys.load_now(team, robot))
        self._subs.append(t.queryable(keys.load(team, robot), lambda: self.newest))
        self._tokens.append(t.declare_token(keys.alive(team, robot)))
        self._subs.append(t.subscribe_liveliness(keys.app(team, robot), lambda key, here: put(("app", here)),
                                                 history=True))
        self._subs.append(t.subscribe_liveliness(keys.where(team, robot), on_where, history=True))
        self._tokens.append(t.declare_token(keys.where(team, robot, incarnation, t.locators())))

    def widen(self, t: Transport | None) -> None:
        """This robot places programs: subscribe to every teammate's periodic
        reports, then fetch their newest (``("views",)`` queued when the
        query is over). Once; a failure leaves it with what arrives."""
        if self.wide:
            return
        self.wide = True
        log.info("node %s places programs: it hears every teammate's load reports from now on", self.robot)

        def reply(data: bytes) -> None:  # on a transport thread
            self.fetched += 1
            self._on_wire(data)

        try:
            assert t is not None
            self._subs.append(t.subscribe(keys.load(self.team), self._on_periodic))
            if self._own is not None:  # the subscription above has its reports too
                self._own.undeclare()
                self._subs.remove(self._own)
                self._own = None
            t.get(keys.load(self.team), reply, lambda: self._put(("views",)), timeout=FETCH_TIMEOUT)
        except Exception as exc:
            log.warning("node %s could not fetch its teammates' load reports: %s", self.robot, exc)
            self._put(("views",))

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
