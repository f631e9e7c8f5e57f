"""The Team API: submit computations to the team from robot code.

How this works: ``ramps.connect()`` opens a Zenoh peer session that joins
the team, finds this robot's node by its liveliness token, and returns a
``Team``. ``team.submit("plan_route", **args)`` checks the arguments against
the program's signature and annotated types (when the program is installed
here too: ``ramps.runtime.argtypes``; else its node does), encodes them with
msgpack and sends one ``SubmitProgram`` to the node; the node is
the origin of the autonomous program and sends back exactly one
``ProgramOutcome``, which resolves the ``concurrent.futures.Future``.

    team = ramps.connect(team="warehouse", robot="r1")
    fut = team.submit("route_plan", picks=8, seed=3)
    print(fut.result())                               # blocks; raises on failure
    results = list(team.map("route_plan", [{"seed": s} for s in range(15)]))
    fast = team.options(timeout=30).submit("route_plan", seed=1)
    value = await team.submit_async("route_plan", seed=2)

``fut.cancel()`` withdraws the program from the team. While it runs,
``fut.state`` ("submitted", "placed", "running", "replaced", "host_failed",
then "done", "failed", "timed_out" or "cancelled"), ``fut.host``, ``fut.attempts`` and ``fut.progress``
(0..1, or None until the program reports any; see ``ramps.progress``) follow
it, and ``fut.add_update_callback(fn)`` calls ``fn(fut)`` on every change.
Once done, ``fut.host`` names the robot that ran it and ``fut.attempts`` how
many placements it took. A per-call timeout
(``team.options(timeout=...)``) cancels the program and raises
``TimeoutError``; a deadline (``team.options(deadline=2.0)``) places it
where it is expected to end in time and sets ``fut.missed_deadline`` when
it did not (see ``Team.options``). Errors are the ``ramps.errors`` tree.

The client reaches the team through ``ramps.runtime.transport`` and reads
time from its injected clock, as the node does (``ramps.testing.memory``
runs it in memory). ``Team`` is the connection to its node (found by its
liveliness; programs lost with it after ``origin_grace``) and the API; its
parts: the pending programs, resent until the node has them and timed out
by a thread of their own (``ramps.runtime.pending``), the futures, how an
outcome settles them and the team's status (``ramps.runtime.futures``), and
the Teams left open, closed at exit (``ramps.runtime.open_teams``). One
lock, the Team's, guards its state and its parts' against the transport's
callback threads and the timer thread.
"""

from __future__ import annotations

import asyncio
import itertools
import os
import socket
import sys
import threading
from concurrent.futures import Future
from typing import Any, Iterable, Iterator

import msgspec

from ramps.core.deadlines import ON_MISS
from ramps.core.messages import CancelSubmitted, ProgramOutcome, ProgramUpdate, SubmitProgram, WireError, decode, encode
from ramps.errors import BadArguments, NoTeam, NotAdmitted, ProgramLost, ProgramNotFound, TransportError
from ramps.runtime import argtypes, keys, open_teams
from ramps.runtime.futures import ProgramFuture, TeamReports, TeamStatus, report_about, settle
from ramps.runtime.pending import Pending
from ramps.runtime.registry import MAX_ARGS_BYTES, Registry, default_registry, encode_args
from ramps.runtime.security import admission, settings_credentials, tls_listeners
from ramps.runtime.settings import NodeSettings, load_settings
from ramps.runtime.transport import REAL_CLOCK, Clock, Transport, ZenohTransport


#: seconds a client waits, by default, for its node to come back before
#: failing the programs it submitted there (``connect(origin_grace=)``): a
#: lease that flapped comes back within ~1 s; a node stalled for a few
#: seconds, frozen or starved of CPU, comes back after its stall plus ~1 s to
#: reconnect; a node restarted by its supervisor comes back with its durable
#: record (``ramps.runtime.store``) and its programs, which hosts keep running
#: for it as long by default (``RampsConfig.origin_hold``)
ORIGIN_GONE_GRACE = 30.0


class Team:
    """A client's connection to its team: get one from ``ramps.connect()``.

    It submits programs to one robot's node (``robot``), the origin of each:
    ``submit`` and ``map`` (and their ``async`` forms) return futures or
    results; ``options(timeout=..., local_only=..., work=..., policy=...)``
    sets them per call; ``status()`` is the team as this client sees it;
    ``pending()`` counts programs not finished; ``close()`` (or ``with``)
    leaves, failing what is still pending with ``ProgramLost``.

    ``submits`` (default True): this client is an application that submits
    programs, so it declares a token (``keys.app``) that tells its robot's
    node so at once, and the node's teammates hear that it is an origin
    before its first program (several origins' bursts then claim robots,
    ``ramps.core.claims``); ``ramps status`` and ``ramps top`` only watch.

    For tests and embedding: ``transport`` (default: a Zenoh session opened
    from ``settings``; closed with the Team) and ``clock`` (default: the real
    one) are its seams to the world, as ``NodeRuntime``'s:
    ``ramps.testing.memory`` has in-memory ones."""

    def __init__(self, settings: NodeSettings, *, robot: str | None, timeout: float,
                 registry: Registry | None = None, transport: Transport | None = None,
                 clock: Clock = REAL_CLOCK, origin_grace: float = ORIGIN_GONE_GRACE, submits: bool = True) -> None:
        if not origin_grace >= 0:
            raise ValueError(f"origin_grace must be >= 0 seconds, got {origin_grace!r}")
        self.clock = clock
        self.origin_grace = origin_grace
        self.team = settings.team
        self.registry = registry or default_registry
        self.client_id = keys.keys_safe_id(f"{socket.gethostname()}-{os.getpid()}-{os.urandom(3).hex()}")
        self._lock = threading.Lock()
        #: the programs submitted and not finished (the timer thread resends and times them out)
        self._pending = Pending(self._lock, clock, send=lambda data: self._pub.put(data),
                                reachable=self._node_reachable, withdraw=self._withdraw)
        self._ids = itertools.count(1)
        self._alive: set[str] = set()
        #: robots whose node said it is leaving (``keys.leaving``), until they are back
        self._leaving: set[str] = set()
        self._reports = TeamReports()
        #: the node's liveliness went (its link lapsed) and has not come back yet
        self._node_lapsed = False
        self._closed = False
        self.secure = settings.secure
        self._connect = list(settings.connect)
        creds, exit_on_failure = None, False
        if settings.secure:  # CredentialsError, NotAdmitted: at once, before Zenoh
            creds = settings_credentials(settings)
            exit_on_failure = admission(settings.connect, creds, team=self.team)
        listen = [] if settings.connect else settings.listen
        try:
            self.transport: Transport = transport or ZenohTransport.open(
                settings, credentials=creds, fail_fast=exit_on_failure, listen=listen, scout_first=False)
        except TransportError as exc:
            raise TransportError(f"cannot open a Zenoh session for team {self.team!r}: {exc}") from exc
        open_teams.track(self)
        t = self.transport
        self._subs = [
            t.subscribe(keys.client(self.team, self.client_id), self._on_outcome),
            t.subscribe(keys.load(self.team), self._on_report),
            t.subscribe_liveliness(keys.alive(self.team), self._on_alive, history=True),
            t.subscribe_liveliness(keys.leaving(self.team), self._on_leaving, history=True),
        ]
        self._timer_thread = threading.Thread(target=self._pending.run, name="ramps-client-timers", daemon=True)
        self._timer_thread.start()
        self.robot = self._find_robot(robot, timeout)
        self._pub = t.publisher(keys.inbox(self.team, self.robot), block=True)
        if submits:
            self._subs.append(t.declare_token(keys.app(self.team, self.robot, self.client_id)))
        self._prepare_checks()

    def _prepare_checks(self) -> None:
        """Import the programs this client knows (the built-ins and those
        registered with ``@ramps.program`` in this process) and read their
        signatures now, so that even the first call of each is checked in
        well under a millisecond. One that does not import here fails when it
        is submitted."""
        for name in sorted(self.registry.names()):
            try:
                fn = self.registry.get(name).function()
                if getattr(fn, "check_args", None) is None:
                    argtypes.prepare(fn)
            except Exception:
                continue

    # ------------------------------------------------------------ discovery
    def _on_alive(self, key: str, alive: bool) -> None:
        """A robot's liveliness key came or went. Zenoh tells a key, not each
        token: two nodes under one name are one key, gone when both are, so a
        refused clone that leaves takes nothing from the node that stays."""
        robot = keys.robot_of(key)
        with self._lock:
            if alive:
                self._alive.add(robot)
                self._leaving.discard(robot)  # back: a new start of its node
                if robot == getattr(self, "robot", None) and self._node_lapsed:
                    # the link to our node is back: an outcome it sent meanwhile went nowhere
                    # (Zenoh may even report a match through another peer); ask about every
                    # pending program again: the node answers where each stands, or resends
                    # the outcome, and never runs a request twice (a node that restarted
                    # meanwhile runs it anew: its programs died with the old one)
                    self._node_lapsed = False
                    self._pending.ask_again()
            else:
                self._alive.discard(robot)
                if robot == getattr(self, "robot", None):
                    self._node_lapsed = True
                if robot == getattr(self, "robot", None) and self._pending.futures and not self._closed:
                    # our node, the origin of every pending program, is gone: unless it
                    # is back soon (a lease that flapped), nobody will ever answer them
                    t = threading.Timer(self.origin_grace, self._origin_gone, args=(robot,))
                    t.daemon = True
                    t.start()

    def _on_leaving(self, key: str, declared: bool) -> None:
        robot = keys.robot_of(key)
        with self._lock:
            if declared:
                self._leaving.add(robot)
            elif robot in self._alive:  # it went with a node that did not leave: not this robot's
                self._leaving.discard(robot)

    def _origin_gone(self, robot: str) -> None:
        with self._lock:
            if robot in self._alive or self._closed:
                return
            futs = self._pending.take_all()
        for f in futs:
            try:
                f.set_exception(ProgramLost(f"{f.program}: robot {robot}, the origin of this program (the node this "
                                            f"client submitted to), left the team or died; the program is lost "
                                            f"with it. Submit it again to another robot's node.", host=f.host,
                                            attempts=f.attempts))
            except Exception:  # done or cancelled meanwhile
                pass

    def _on_report(self, data: bytes) -> None:
        """A periodic load report: kept as it came (``TeamReports``)."""
        robot = report_about(data)
        if robot:
            with self._lock:
                self._reports.keep(robot, data, self.clock.monotonic())

    def _find_robot(self, robot: str | None, timeout: float) -> str:
        deadline = self.clock.monotonic() + timeout
        # not secured, linked to nobody after a second: is the team a secured one?
        probe_at = self.clock.monotonic() + 1.0 if not self.secure and self._connect else None
        while True:
            with self._lock:
                alive = sorted(self._alive)
            if robot is not None and robot in alive:
                return robot
            if robot is None and alive:
                host = keys.keys_safe_id(socket.gethostname())
                return host if host in alive else alive[0]
            if probe_at is not None and self.clock.monotonic() >= probe_at:
                probe_at = None
                secured = [] if self.transport.peers() else tls_listeners(self._connect)
                if secured:
                    self.close()
                    raise NotAdmitted(f"team {self.team!r} at {', '.join(secured)} is secured (TLS, team "
                                      "certificates) and this client is not: connect with --secure --credentials "
                                      "DIR (ramps.connect(..., secure=True, credentials=DIR))")
            if self.clock.monotonic() >= deadline:
                self.close()
                want = f"node {robot!r}" if robot else "any node"
                seen = f" (robots seen: {', '.join(alive)})" if alive else ""
                hint = (" In secure mode, check that the team's robots run with --secure and that these "
                        "credentials come from the same team CA." if self.secure else "")
                raise NoTeam(f"{want} of team {self.team!r} could not be reached within {timeout:g} s{seen}; "
                             "is `ramps node` running, and are the team name and endpoints right?" + hint)
            self.clock.sleep(0.02)

    # ------------------------------------------------------------ submitting
    def options(self, *, timeout: float | None = None, local_only: bool = False, work: float | None = None,
                policy: str = "", deadline: float | None = None, on_miss: str = "run") -> "_Options":
        """Per-call options: ``team.options(timeout=30).submit(...)``.

        ``timeout``: withdraw the program and raise TimeoutError after this
        many seconds; ``local_only``: run it on the origin robot only;
        ``work``: expected work units (overrides the program's profile);
        ``policy``: placement policy for these calls (default: the node's);
        ``deadline``: seconds from submission by which the result is wanted:
        the program goes to a robot expected to finish in time, and a late
        result sets ``fut.missed_deadline``; ``on_miss``: what to do when no
        robot is expected to make it: "run" it where it ends soonest anyway
        (the default), run it on the "local" robot, or "fail" at once with
        ``DeadlineUnmeetable`` (nothing runs). A deadline does not withdraw
        a late program; ``timeout`` does."""
        if deadline is not None and not (isinstance(deadline, (int, float)) and not isinstance(deadline, bool)
                                         and 0 < deadline <= sys.float_info.max):  # not NaN, inf, 10**400
            raise ValueError(f"deadline is seconds from submission, > 0; got {deadline!r}")
        if on_miss not in ON_MISS:
            raise ValueError(f"on_miss must be one of {', '.join(ON_MISS)}; got {on_miss!r}")
        return _Options(self, timeout=timeout, local_only=local_only, work=work, policy=policy,
                        deadline=deadline, on_miss=on_miss)

    def submit(self, program: str, /, **kwargs: Any) -> ProgramFuture:
        """Run ``program`` (a name registered on the team's robots) with these
        keyword arguments somewhere on the team; returns at once.

        The arguments are checked against the program's signature and
        annotated types first when this process knows the program
        (``BadArguments``, nothing sent), else by the node. The returned
        ``ProgramFuture`` is a ``concurrent.futures.Future``: ``result()``
        gives the program's return value or raises ``ProgramFailed`` (the
        program raised, or killed its worker on several robots),
        ``ProgramRefused``, ``ProgramLost`` or ``BadArguments``;
        ``cancel()`` withdraws it from the team; ``state``, ``host``,
        ``attempts`` and ``progress`` follow it while it runs.

            fut = team.submit("route_plan", picks=8, seed=3)
            plan = fut.result(timeout=60)"""
        return self._submit(program, kwargs)

    def map(self, program: str, calls: Iterable[dict[str, Any]], *, timeout: float | None = None) -> Iterator[Any]:
        """Submit one program per dict of arguments, all at once; yield their
        results in the order of ``calls`` (the first error raises, and the
        programs not yet collected are withdrawn). ``timeout``: seconds each
        call may take (TimeoutError).

            for plan in team.map("route_plan", [{"seed": s} for s in range(6)]):
                print(plan["length"])"""
        return self.options(timeout=timeout).map(program, calls)

    async def submit_async(self, program: str, /, **kwargs: Any) -> Any:
        """``await team.submit_async("route_plan", seed=2)``: ``submit``, awaited
        for its result (cancelling the awaiting task withdraws the program)."""
        return await asyncio.wrap_future(self._submit(program, kwargs))

    async def map_async(self, program: str, calls: Iterable[dict[str, Any]]) -> list[Any]:
        """``map`` for asyncio: every call at once, their results as a list in
        the order of ``calls`` (the first error raises)."""
        futs = [asyncio.wrap_future(self._submit(program, dict(c))) for c in calls]
        return list(await asyncio.gather(*futs))

    def _submit(self, program: str, kwargs: dict[str, Any], *, timeout: float | None = None,
                local_only: bool = False, work: float | None = None, policy: str = "",
                deadline: float | None = None, on_miss: str = "run") -> ProgramFuture:
        if self._closed:
            raise RuntimeError("this Team is closed")
        if not isinstance(program, str) or not program:
            raise ProgramNotFound(f"a program name is a non-empty string, not {program!r}")
        if program in self.registry:
            spec = self.registry.get(program)
            args = encode_args(spec, kwargs)
            work = work if work is not None else spec.declared_work(kwargs)
        else:  # not installed here: the robot's node checks it
            try:
                args = msgspec.msgpack.encode(kwargs)
            except (TypeError, msgspec.EncodeError) as exc:
                raise BadArguments(f"arguments of {program!r} cannot be sent (msgpack only): {exc}") from None
            if len(args) > MAX_ARGS_BYTES:
                raise BadArguments(f"arguments of {program!r} are {len(args)} bytes; the limit is {MAX_ARGS_BYTES}")
        rid = next(self._ids)
        fut = ProgramFuture(program)
        with self._lock:
            self._pending.add(rid, fut, timeout)
        fut.add_done_callback(lambda f: self._on_done(rid, f))
        msg = SubmitProgram(client=self.client_id, request_id=rid, program=program, args=args,
                            work=work or 0.0, local_only=local_only, policy=policy,
                            deadline=None if deadline is None else float(deadline),
                            on_miss="" if on_miss == "run" else on_miss)
        data = encode(self.client_id, msg)
        # until the node acknowledges it (an update or the outcome), the timer thread sends it again: a
        # submission published while the node's link lapsed (a node stalled, starved of CPU) is lost
        reachable = self._node_reachable()
        with self._lock:
            self._pending.sending(rid, data, reachable)
        if not reachable:
            return fut
        try:
            self._pub.put(data)
        except Exception as exc:
            with self._lock:
                self._pending.forget(rid)
            raise TransportError(f"could not send {program!r} to {self.robot}: {exc}") from exc
        return fut

    def _node_reachable(self) -> bool:
        """Whether this client's node subscribes to what it publishes right now
        (False while the link is down: a put would go nowhere, and a
        submission is sent only once)."""
        try:
            return bool(self._pub.matching())
        except Exception:  # cannot tell: send
            return True

    def _on_done(self, rid: int, fut: Future) -> None:
        with self._lock:
            self._pending.forget(rid)
        if fut.cancelled() and not self._closed:
            try:
                self._withdraw(rid)
            except Exception:
                pass

    def _withdraw(self, rid: int) -> None:
        """Tell the node to withdraw program ``rid`` (raises what the transport raises)."""
        self._pub.put(encode(self.client_id, CancelSubmitted(client=self.client_id, request_id=rid)))

    def _on_outcome(self, data: bytes) -> None:
        try:
            env = decode(data)
        except WireError:
            return
        o = env.msg
        if isinstance(o, ProgramUpdate):
            with self._lock:
                fut = self._pending.acked(o.request_id)  # the node has it
            if fut is not None:
                fut._updated(o)
            return
        if not isinstance(o, ProgramOutcome):
            return
        with self._lock:
            fut = self._pending.forget(o.request_id)
        if fut is not None and not fut.done():
            settle(fut, o, env.sender)

    # ------------------------------------------------------------ looking
    def status(self) -> TeamStatus:
        """The team as this client sees it now: one ``RobotStatus`` per robot
        (alive by its liveliness token; cores, speed, CPU use, the programs
        it runs and more from its latest load report, with the report's age).
        What ``ramps status`` prints."""
        now = self.clock.monotonic()
        with self._lock:
            return self._reports.status(self.team, self._alive, self._leaving, now)

    def pending(self) -> int:
        """How many of this client's programs have not finished yet."""
        with self._lock:
            return len(self._pending.futures)

    # ------------------------------------------------------------ closing
    def close(self) -> None:
        """Leave the team: futures still pending fail here with
        ``ProgramLost`` (their programs are not withdrawn: ``cancel()`` them
        first for that) and the Zenoh session closes. Idempotent; ``with
        ramps.connect(...) as team:`` calls it, and a Team left open is
        closed at interpreter exit."""
        if self._closed:
            return
        with self._lock:
            self._closed = True
            futs = self._pending.take_all()
            self._pending.stop()
        for f in futs:
            if not f.done():
                f.set_exception(ProgramLost("the Team connection was closed before the program finished"))
        for sub in getattr(self, "_subs", []):
            try:
                sub.undeclare()
            except Exception:
                pass
        try:
            self.transport.close()
        except Exception:
            pass
        open_teams.forget(self)

    def __enter__(self) -> "Team":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class _Options:
    """Per-call options bound to a Team (``team.options(...)``): its
    ``submit``, ``map`` and ``submit_async`` are the Team's, with them."""

    def __init__(self, team: Team, **opts: Any) -> None:
        self._team = team
        self._opts = opts

    def submit(self, program: str, /, **kwargs: Any) -> ProgramFuture:
        return self._team._submit(program, kwargs, **self._opts)

    def map(self, program: str, calls: Iterable[dict[str, Any]]) -> Iterator[Any]:
        futs = [self.submit(program, **dict(c)) for c in calls]

        def results() -> Iterator[Any]:
            try:
                for f in futs:
                    yield f.result()
            finally:
                for f in futs:
                    f.cancel()

        return results()

    async def submit_async(self, program: str, /, **kwargs: Any) -> Any:
        return await asyncio.wrap_future(self.submit(program, **kwargs))


def connect(team: str | None = None, robot: str | None = None, *, connect: list[str] | None = None,
            listen: list[str] | None = None, multicast: bool | None = None, timeout: float = 5.0,
            config_file: str | os.PathLike | None = None, registry: Registry | None = None, secure: bool | None = None,
            credentials: str | os.PathLike | None = None, origin_grace: float = ORIGIN_GONE_GRACE,
            mode: str | None = None) -> Team:
    """Join a team as an application and return a ``Team``: what
    ``ramps.connect`` does, whose docstring says what each argument means
    (``help(ramps.connect)``). Raises ``NoTeam`` if no node answers within
    ``timeout`` seconds."""
    settings = load_settings(config_file=config_file, default_robot=False, flags={
        "team": team, "connect": connect, "listen": listen, "multicast": multicast, "secure": secure,
        "credentials": str(credentials) if credentials is not None else None, "mode": mode,
    })
    return Team(settings, robot=robot, timeout=timeout, registry=registry, origin_grace=origin_grace)
