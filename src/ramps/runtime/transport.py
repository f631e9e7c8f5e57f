"""The seam between the runtime's drivers (node, client) and Zenoh.

How this works: ``NodeRuntime`` and ``ramps.connect()`` talk to the team
only through a ``Transport``: publish bytes on a key (with or without
blocking when the link is congested), subscribe to a key expression with a
callback ``(bytes)`` (the drivers never need a sample's key: reading it
from Zenoh cost about 0.8 us a message, a third of the callback), declare a liveliness token and watch the team's
tokens ``(key, alive)``, ask whether a key has a subscriber now, answer
queries on a key with the newest bytes there (a queryable) and query a key
expression once (``get``: each reply's bytes to a callback, then a call
that says the query is over), list the locators and peers, close. ``ZenohTransport`` is that over a real Zenoh
session (the only place in the drivers that touches ``zenoh`` objects);
``ramps.testing.memory.MemoryTransport`` is the same over an in-process bus,
so a driver's logic runs in tests in milliseconds, without processes.

Time goes through a ``Clock`` (``monotonic``, ``time``, ``sleep``):
``REAL_CLOCK`` in production, a fake one in tests
(``ramps.testing.memory.FakeClock``).

Zenoh errors surface as ``ramps.errors.TransportError`` with Zenoh's words.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING, Any, Callable, Protocol

from ramps.errors import TransportError

if TYPE_CHECKING:
    from ramps.runtime.settings import NodeSettings

#: a subscriber's callback: the sample's bytes
OnSample = Callable[[bytes], None]
#: a liveliness subscriber's callback: the token's key, and whether it came (True) or went
OnAlive = Callable[[str, bool], None]
#: a queryable's answer: the bytes to reply with (None: no reply)
Answer = Callable[[], bytes | None]


class Clock(Protocol):
    """Where a driver reads time: ``monotonic()`` for deadlines, ``time()``
    for wall stamps in traces, ``sleep()`` for its few deliberate pauses."""

    def monotonic(self) -> float: ...

    def time(self) -> float: ...

    def sleep(self, seconds: float) -> None: ...


class RealClock:
    """The process's clocks: ``time.monotonic``, ``time.time`` and ``time.sleep``
    themselves (a node's driver reads the clock several times a message)."""

    monotonic = staticmethod(time.monotonic)
    sleep = staticmethod(time.sleep)
    time = staticmethod(time.time)


REAL_CLOCK = RealClock()


class Declared(Protocol):
    """A subscriber or token: ``undeclare()`` ends it."""

    def undeclare(self) -> None: ...


class Publisher(Protocol):
    """A declared publisher on one key."""

    def put(self, data: bytes) -> None: ...

    def matching(self) -> bool:
        """Whether some subscriber matches its key now."""
        ...

    def undeclare(self) -> None: ...


class Transport(Protocol):
    """What a driver needs of the team's network (see the module's docstring)."""

    def subscribe(self, key: str, callback: OnSample) -> Declared: ...

    def subscribe_liveliness(self, key: str, callback: OnAlive, *, history: bool = True) -> Declared: ...

    def declare_token(self, key: str) -> Declared: ...

    def publisher(self, key: str, *, block: bool = False) -> Publisher: ...

    def put(self, key: str, data: bytes, *, block: bool = False) -> None: ...

    def queryable(self, key: str, answer: Answer) -> Declared:
        """Answer every query that matches ``key`` with ``answer()``, under ``key``."""
        ...

    def get(self, key: str, on_reply: OnSample, on_done: Callable[[], None], *, timeout: float) -> None:
        """Query ``key`` (an expression) once, without waiting: each reply's
        bytes go to ``on_reply``, then ``on_done`` is called once, after the
        last reply or ``timeout`` seconds (also when the query could not go)."""
        ...

    def locators(self) -> list[str]: ...

    def peers(self) -> list[str]: ...

    def close(self) -> None: ...


class _ZenohPublisher:
    """A Zenoh publisher. Whether a subscriber matches its key is asked of
    Zenoh once (``matching_status``, about 10 us in a node's session: a
    client asks before each submission, a node before each outcome), then
    kept by a matching listener, which Zenoh tells of every change."""

    #: publish ``data`` (Zenoh's own method: a node puts twice a program)
    put: Callable[[bytes], None]

    def __init__(self, pub: Any) -> None:
        self._pub = pub
        self.put = pub.put
        self._listener: Any = None
        self._matching = False

    def matching(self) -> bool:
        if self._listener is None:
            try:  # the listener first, so no change after the status asked is missed
                self._listener = self._pub.declare_matching_listener(self._on_matching)
            except Exception:  # cannot listen: ask each time
                return bool(self._pub.matching_status.matching)
            self._matching = bool(self._pub.matching_status.matching)
        return self._matching

    def _on_matching(self, status: Any) -> None:
        """Zenoh's matching listener (on one of its threads): a subscriber came or the last went."""
        self._matching = bool(status.matching)

    def undeclare(self) -> None:
        if self._listener is not None:
            try:
                self._listener.undeclare()
            except Exception:  # its session closed: gone with it
                pass
            self._listener = None
        self._pub.undeclare()


class ZenohTransport:
    """A ``Transport`` over one Zenoh session (owned: ``close()`` closes it)."""

    def __init__(self, session: Any) -> None:
        import zenoh

        self._z = zenoh
        self.session = session
        #: the listen endpoints asked for, and the TCP sockets this process
        #: began to listen on while the session opened (address, port)
        self._asked: list[str] = []
        self._bound: list[tuple[str, int]] = []

    @classmethod
    def open(cls, settings: "NodeSettings", *, credentials: Any = None, fail_fast: bool = False,
             listen: list[str] | None = None, scout_first: bool = True) -> "ZenohTransport":
        """A session for ``settings`` as ``ramps node`` and ``ramps.connect``
        open it: TLS with this robot's ``credentials`` on a secured team
        (``security.open_session``), else plain. ``scout_first``: see
        ``zenoh_config`` (False for an application). Raises TransportError."""
        import zenoh

        from ramps.runtime.security import open_session
        from ramps.runtime.zenoh_configs import zenoh_config

        zenoh.try_init_log_from_env()  # RUST_LOG=zenoh=debug shows Zenoh's own view (links, leases)
        extra: dict[str, Any] = {"scout_first": scout_first}
        if listen is not None:
            extra["listen"] = listen
        before = _listening()
        try:
            if settings.secure:
                session = open_session(
                    lambda fast: zenoh_config(settings, credentials=credentials, exit_on_failure=fast, **extra),
                    settings.connect, credentials, team=settings.team, fail_fast=fail_fast)
            else:
                session = zenoh.open(zenoh_config(settings, **extra))
        except zenoh.ZError as exc:
            raise TransportError(explain_open_error(settings, exc)) from exc
        t = cls(session)
        t._asked = [] if settings.mode == "client" else settings.listen_endpoints(listen)
        t._bound = sorted(_listening() - before)
        return t

    def subscribe(self, key: str, callback: OnSample) -> Declared:
        try:
            return self.session.declare_subscriber(
                key, lambda smp: callback(smp.payload.to_bytes()))
        except self._z.ZError as exc:
            raise TransportError(str(exc)) from exc

    def subscribe_liveliness(self, key: str, callback: OnAlive, *, history: bool = True) -> Declared:
        put = self._z.SampleKind.PUT
        try:
            return self.session.liveliness().declare_subscriber(
                key, lambda smp: callback(str(smp.key_expr), smp.kind == put), history=history)
        except self._z.ZError as exc:
            raise TransportError(str(exc)) from exc

    def declare_token(self, key: str) -> Declared:
        try:
            return self.session.liveliness().declare_token(key)
        except self._z.ZError as exc:
            raise TransportError(str(exc)) from exc

    def _cc(self, block: bool) -> Any:
        return self._z.CongestionControl.BLOCK if block else self._z.CongestionControl.DROP

    def publisher(self, key: str, *, block: bool = False) -> Publisher:
        try:
            return _ZenohPublisher(self.session.declare_publisher(key, congestion_control=self._cc(block)))
        except self._z.ZError as exc:
            raise TransportError(str(exc)) from exc

    def put(self, key: str, data: bytes, *, block: bool = False) -> None:
        self.session.put(key, data, congestion_control=self._cc(block))

    def queryable(self, key: str, answer: Answer) -> Declared:
        def on_query(query: Any) -> None:  # on a Zenoh callback thread: answer() only reads
            try:
                data = answer()
                if data is not None:
                    query.reply(key, data)
            except Exception:
                pass  # the querier gets no reply from this robot, as from one that is gone
            finally:
                query.drop()

        try:
            return self.session.declare_queryable(key, on_query)
        except self._z.ZError as exc:
            raise TransportError(str(exc)) from exc

    def get(self, key: str, on_reply: OnSample, on_done: Callable[[], None], *, timeout: float) -> None:
        z = self._z

        def reply(r: Any) -> None:
            if r.ok is not None:
                on_reply(r.ok.payload.to_bytes())

        try:
            self.session.get(key, z.handlers.Callback(reply, on_done), target=z.QueryTarget.ALL,
                             consolidation=z.ConsolidationMode.NONE, timeout=timeout)
        except Exception:
            on_done()

    def locators(self) -> list[str]:
        """Where this session listens, with the real ports: Zenoh's own list
        where its Python API has one, else each endpoint asked for with a
        port 0 replaced by the port its listener was given (found among the
        TCP sockets this process began to listen on as the session opened)."""
        info = self.session.info
        if hasattr(info, "locators"):
            return [str(x) for x in info.locators()]
        return [real_endpoint(e, self._bound) for e in self._asked]

    def peers(self) -> list[str]:
        return [str(z) for z in self.session.info.peers_zid()]

    def close(self) -> None:
        self.session.close()


def _listening() -> set[tuple[str, int]]:
    """The TCP sockets this process listens on: (address, port)."""
    try:
        import psutil

        return {(c.laddr.ip, c.laddr.port) for c in psutil.Process().net_connections(kind="tcp")
                if c.status == psutil.CONN_LISTEN}
    except Exception:  # cannot tell (no permission, no psutil): the banner shows what was asked
        return set()


def real_endpoint(endpoint: str, bound: list[tuple[str, int]]) -> str:
    """``tcp/0.0.0.0:0`` (or ``tls/``, ``ws/``) with the port its listener got:
    the one socket in ``bound`` on that address; unchanged if it has a port
    already, or if that cannot be told."""
    proto, sep, rest = endpoint.partition("/")
    addr, colon, port = rest.split("#", 1)[0].rpartition(":")
    if not sep or not colon or port != "0" or proto not in ("tcp", "tls", "ws"):
        return endpoint
    host = addr.strip("[]")
    ports = {p for a, p in bound if a == host or (host in ("0.0.0.0", "::") and a in ("0.0.0.0", "::"))}
    return f"{proto}/{addr}:{ports.pop()}" if len(ports) == 1 else endpoint


def explain_open_error(settings: "NodeSettings", exc: Exception) -> str:
    """Zenoh's words for a session that did not open, with what to do when we know.

    A client (``mode = "client"``) opens only once it has linked to a router:
    with none reachable Zenoh says "Unable to connect to any of [...]"."""
    text = str(exc).split(" at /")[0]
    if getattr(settings, "mode", "peer") == "client" and "Unable to connect" in text:
        where = ", ".join(settings.connect) or "any router found by multicast scouting"
        return (f"client mode: no router reachable at {where} ({text}); is `ramps router` running there, "
                "and is the endpoint right? A client reaches its team only through a router")
    if "Address already in use" in text or "address already in use" in text.lower():
        return f"{text}: another process (a node, a router) already listens on that endpoint"
    return text


__all__ = ["Answer", "Clock", "Declared", "OnAlive", "OnSample", "Publisher", "REAL_CLOCK", "RealClock", "Transport",
           "ZenohTransport", "explain_open_error"]
