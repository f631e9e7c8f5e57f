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
runs it in memory). Over 500 lines for a reason: ``Team`` is one class
whose threads (transport callbacks, timers) share one lock and its state;
its futures live in ``ramps.runtime.futures``.
"""

from __future__ import annotations

import asyncio
import atexit
import heapq
import itertools
import os
import socket
import sys
import threading
import weakref
from concurrent.futures import Future
from typing import Any, Iterable, Iterator

import msgspec

from ramps.core.messages import (
    CancelSubmitted,
    LoadReport,
    ProgramOutcome,
    ProgramUpdate,
    SubmitProgram,
    WireError,
    decode,
    encode,
)
from ramps.errors import (
    BadArguments,
    DeadlineUnmeetable,
    NoTeam,
    NotAdmitted,
    ProgramFailed,
    ProgramLost,
    ProgramNotFound,
    ProgramRefused,
    TransportError,
)
from ramps.runtime import argtypes, keys
from ramps.runtime.registry import MAX_ARGS_BYTES, Registry, decode_value, default_registry, encode_args
from ramps.runtime.security import admission, settings_credentials, tls_listeners
from ramps.runtime.settings import NodeSettings, load_settings
from ramps.runtime.futures import ProgramFuture, RobotStatus, TeamStatus, report_about
from ramps.runtime.transport import REAL_CLOCK, Clock, Transport, ZenohTransport


#: seconds a client waits, by default, for its node to come back before
#: failing the programs it submitted there (``connect(origin_grace=)``): a
#: lease that flapped comes back within ~1 s; a node stalled for a few
#: seconds, frozen or starved of CPU, comes back after its stall plus ~1 s to
#: reconnect; a node restarted by its supervisor comes back with its durable
#: record (``ramps.runtime.store``) and its programs, which hosts keep running
#: for it as long by default (``RampsConfig.origin_hold``)
ORIGIN_GONE_GRACE = 30.0
#: seconds between two looks for the node while submissions wait for it
HELD_RETRY = 0.05
#: a submission the node has not acknowledged (no update, no outcome) is sent
#: again after this many seconds; the node runs one program per request
SUBMIT_RESEND = 1.0

_ERRORS = {"program": ProgramFailed, "refused": ProgramRefused, "bad_arguments": BadArguments,
           "deadline": DeadlineUnmeetable}
#: what a call with a deadline may do when no robot can meet it (``Team.options``)
ON_MISS = ("run", "local", "fail")


#: Teams still open, closed at interpreter exit if the application did not
_OPEN: "weakref.WeakSet[Team]" = weakref.WeakSet()
_OPEN_LOCK = threading.Lock()
_EXIT_HOOKED = False


def _close_open_teams() -> None:
    """Close every Team the application left open. Zenoh runs subscriber
    callbacks on non-daemon threads, so an open session would keep the
    process alive after the script's last line; this runs before Python
    waits for those threads (plain ``atexit`` would be too late)."""
    with _OPEN_LOCK:
        teams = list(_OPEN)
    for team in teams:
        try:
            team.close()
        except Exception:
            pass


def _track(team: "Team") -> None:
    global _EXIT_HOOKED
    with _OPEN_LOCK:
        _OPEN.add(team)
        if not _EXIT_HOOKED:
            try:  # the hook concurrent.futures uses: before non-daemon threads are joined
                threading._register_atexit(_close_open_teams)  # type: ignore[attr-defined]
            except (AttributeError, RuntimeError):
                atexit.register(_close_open_teams)
            _EXIT_HOOKED = True


class Team:
    """A client's connection to its team: get one from ``ramps.connect()``.

    It submits programs to one robot's node (``robot``), the origin of each:
    ``submit`` and ``map`` (and their ``async`` forms) return futures or
    results; ``options(timeout=..., local_only=..., work=..., policy=...)``
    sets them per call; ``status()`` is the team as this client sees it;
    ``pending()`` counts programs not finished; ``close()`` (or ``with``)
    leaves, failing what is still pending with ``ProgramLost``.

    For tests and embedding: ``transport`` (default: a Zenoh session opened
    from ``settings``; closed with the Team) and ``clock`` (default: the real
    one) are its seams to the world, as ``NodeRuntime``'s:
    ``ramps.testing.memory`` has in-memory ones."""

    def __init__(self, settings: NodeSettings, *, robot: str | None, timeout: float,
                 registry: Registry | None = None, transport: Transport | None = None,
                 clock: Clock = REAL_CLOCK, origin_grace: float = ORIGIN_GONE_GRACE) -> None:
        if not origin_grace >= 0:
            raise ValueError(f"origin_grace must be >= 0 seconds, got {origin_grace!r}")
        self.clock = clock
        self.origin_grace = origin_grace
        self.team = settings.team
        self.registry = registry or default_registry
        self.client_id = keys.keys_safe_id(f"{socket.gethostname()}-{os.getpid()}-{os.urandom(3).hex()}")
        self._lock = threading.Lock()
        self._futures: dict[int, ProgramFuture] = {}
        self._ids = itertools.count(1)
        self._alive: set[str] = set()
        #: robots whose node said it is leaving (``keys.leaving``), until they are back
        self._leaving: set[str] = set()
        self._reports: dict[str, tuple[LoadReport, float]] = {}
        #: each robot's newest load report as it came, not decoded yet (``_on_report``)
        self._raw_reports: dict[str, tuple[bytes, float]] = {}
        self._timers: list[tuple[float, int]] = []
        self._timer_cv = threading.Condition(self._lock)
        #: when the timer thread wakes next, monotonic (-inf while it runs): a new
        #: timer or resend wakes it only if due sooner (``_wake_timers``)
        self._timer_wake_at = -float("inf")
        #: submissions the node has not acknowledged yet: request id -> (bytes, when to send again)
        self._unacked: dict[int, tuple[bytes, float]] = {}
        #: every pending submission as sent, to ask again once the node's link is back after a lapse
        self._sent: dict[int, bytes] = {}
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
        _track(self)
        t = self.transport
        self._subs = [
            t.subscribe(keys.client(self.team, self.client_id), self._on_outcome),
            t.subscribe(keys.load(self.team), self._on_report),
            t.subscribe_liveliness(keys.alive(self.team), self._on_alive, history=True),
            t.subscribe_liveliness(keys.leaving(self.team), self._on_leaving, history=True),
        ]
        self._timer_thread = threading.Thread(target=self._timeouts, name="ramps-client-timers", daemon=True)
        self._timer_thread.start()
        self.robot = self._find_robot(robot, timeout)
        self._pub = t.publisher(keys.inbox(self.team, self.robot), block=True)
        self._prepare_checks()

    def _prepare_checks(self) -> None:
        """Import the programs this client knows (the built-ins and those
        registered with ``@ramps.program`` in this process) and read their
        signatures now, so that even the first call of each is checked in
        well under a millisecond. One that does not import here is left to
        fail, as before, when it is submitted."""
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
                    now = self.clock.monotonic()
                    for rid in self._futures:
                        if rid in self._sent:
                            self._unacked[rid] = (self._sent[rid], now)
                    self._timer_cv.notify()
            else:
                self._alive.discard(robot)
                if robot == getattr(self, "robot", None):
                    self._node_lapsed = True
                if robot == getattr(self, "robot", None) and self._futures and not self._closed:
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
            futs = list(self._futures.values())
            self._futures.clear()
        for f in futs:
            try:
                f.set_exception(ProgramLost(f"{f.program}: robot {robot}, the origin of this program (the node this "
                                            f"client submitted to), left the team or died; the program is lost "
                                            f"with it. Submit it again to another robot's node.", host=f.host,
                                            attempts=f.attempts))
            except Exception:  # done or cancelled meanwhile
                pass

    def _on_report(self, data: bytes) -> None:
        """A periodic load report (reports of the instant go to nodes only):
        kept as it came, read only as far as the robot it is about;
        ``status()`` decodes the newest of each robot, so a client that never
        asks decodes none. A newest report that turns out malformed leaves
        the one decoded before."""
        robot = report_about(data)
        if robot:
            with self._lock:
                self._raw_reports[robot] = (data, self.clock.monotonic())

    def _decode_reports(self) -> None:
        """With the lock held: the newest report of each robot, decoded (see ``_on_report``)."""
        raw, self._raw_reports = self._raw_reports, {}
        for robot, (data, at) in raw.items():
            try:
                env = decode(data)
            except WireError:
                continue
            if isinstance(env.msg, LoadReport) and env.msg.robot == robot:
                self._reports[robot] = (env.msg, at)

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
            self._futures[rid] = fut
            if timeout is not None:
                when = self.clock.monotonic() + timeout
                heapq.heappush(self._timers, (when, rid))
                self._wake_timers(when)
        fut.add_done_callback(lambda f: self._on_done(rid, f))
        msg = SubmitProgram(client=self.client_id, request_id=rid, program=program, args=args,
                            work=work or 0.0, local_only=local_only, policy=policy,
                            deadline=None if deadline is None else float(deadline),
                            on_miss="" if on_miss == "run" else on_miss)
        data = encode(self.client_id, msg)
        # until the node acknowledges it (an update or the outcome), _timeouts sends it again: a
        # submission published while the node's link lapsed (a node stalled, starved of CPU) is lost
        reachable = self._node_reachable()
        with self._lock:
            again = self.clock.monotonic() + (SUBMIT_RESEND if reachable else 0.0)
            self._unacked[rid] = (data, again)
            self._sent[rid] = data
            self._wake_timers(again)
        if not reachable:
            return fut
        try:
            self._pub.put(data)
        except Exception as exc:
            with self._lock:
                self._futures.pop(rid, None)
                self._unacked.pop(rid, None)
                self._sent.pop(rid, None)
            raise TransportError(f"could not send {program!r} to {self.robot}: {exc}") from exc
        return fut

    def _wake_timers(self, due: float) -> None:
        """With the lock held: wake the timer thread if something is now due
        before it would wake (a burst of submissions, each resent only after
        ``SUBMIT_RESEND``, wakes it none)."""
        if due < self._timer_wake_at:
            self._timer_wake_at = -float("inf")
            self._timer_cv.notify()

    def _node_reachable(self) -> bool:
        """Whether this client's node subscribes to what it publishes right now
        (False while the link is down: a put would go nowhere, and a
        submission is sent only once)."""
        try:
            return bool(self._pub.matching())
        except Exception:  # cannot tell: send
            return True

    def _resend_unacked(self) -> float | None:
        """With the lock held: send again the submissions that are due, if
        the node is reachable (withdrawn ones are forgotten). Returns the
        seconds until the next is due."""
        now = self.clock.monotonic()
        due = [(rid, data) for rid, (data, at) in self._unacked.items() if at <= now]
        if due and self._node_reachable():
            for rid, data in due:
                if rid not in self._futures:
                    self._unacked.pop(rid, None)
                    continue
                self._unacked[rid] = (data, now + SUBMIT_RESEND)
                self._lock.release()
                try:
                    self._pub.put(data)
                except Exception:
                    pass
                finally:
                    self._lock.acquire()
        if not self._unacked:
            return None
        return max(HELD_RETRY, min(at for _, at in self._unacked.values()) - self.clock.monotonic())

    def _on_done(self, rid: int, fut: Future) -> None:
        with self._lock:
            self._futures.pop(rid, None)
            self._unacked.pop(rid, None)
            self._sent.pop(rid, None)
        if fut.cancelled() and not self._closed:
            try:
                self._pub.put(encode(self.client_id, CancelSubmitted(client=self.client_id, request_id=rid)))
            except Exception:
                pass

    def _on_outcome(self, data: bytes) -> None:
        try:
            env = decode(data)
        except WireError:
            return
        o = env.msg
        if isinstance(o, ProgramUpdate):
            with self._lock:
                fut = self._futures.get(o.request_id)
                self._unacked.pop(o.request_id, None)  # the node has it
            if fut is not None:
                fut._updated(o)
            return
        if not isinstance(o, ProgramOutcome):
            return
        with self._lock:
            fut = self._futures.pop(o.request_id, None)
            self._unacked.pop(o.request_id, None)
            self._sent.pop(o.request_id, None)
        if fut is None or fut.done():
            return
        fut.host = o.host  # which robot ran it
        fut.attempts = o.attempts
        fut.moves, fut.resumed_from = o.moves, o.resumed_from
        fut.missed_deadline = o.missed_deadline
        try:
            if o.ok:
                try:
                    value = decode_value(o.value)
                except Exception as exc:  # a result this client cannot read is an error, never a hang
                    fut.set_exception(ProgramFailed(f"{fut.program} on {o.host or env.sender}: its result could not "
                                                    f"be decoded ({type(exc).__name__}: {exc})", host=o.host,
                                                    attempts=o.attempts))
                    return
                fut.set_result(value)
            else:
                cls = _ERRORS.get(o.error_kind, ProgramLost)
                if cls is BadArguments:
                    fut.set_exception(BadArguments(o.error))
                else:
                    fut.set_exception(cls(f"{fut.program} on {o.host or env.sender}: {o.error}", host=o.host,
                                          attempts=o.attempts))
        except Exception:  # the future was cancelled meanwhile
            pass

    def _timeouts(self) -> None:
        with self._lock:
            while not self._closed:
                retry = self._resend_unacked() if self._unacked else None
                if not self._timers:
                    self._wait_timers(retry or 0.5)
                    continue
                when, rid = self._timers[0]
                delay = when - self.clock.monotonic()
                if delay > 0:
                    self._wait_timers(min(delay, retry) if retry else delay)
                    continue
                heapq.heappop(self._timers)
                fut = self._futures.get(rid)
                if fut is not None and not fut.done():
                    self._lock.release()
                    try:
                        try:
                            fut.set_exception(TimeoutError(f"{fut.program} did not finish in time; withdrawn"))
                        except Exception:
                            pass
                        self._pub.put(encode(self.client_id, CancelSubmitted(client=self.client_id, request_id=rid)))
                    except Exception:
                        pass
                    finally:
                        self._lock.acquire()

    def _wait_timers(self, seconds: float) -> None:
        """With the lock held: the timer thread waits ``seconds``, or until woken."""
        self._timer_wake_at = self.clock.monotonic() + seconds
        self._timer_cv.wait(seconds)
        self._timer_wake_at = -float("inf")

    # ------------------------------------------------------------ looking
    def status(self) -> TeamStatus:
        """The team as this client sees it now: one ``RobotStatus`` per robot
        (alive by its liveliness token; cores, speed, CPU use, the programs
        it runs and more from its latest load report, with the report's age).
        What ``ramps status`` prints."""
        now = self.clock.monotonic()
        with self._lock:
            self._decode_reports()
            names = sorted(self._alive | set(self._reports))
            rows = []
            for name in names:
                got = self._reports.get(name)
                base: dict[str, Any] = dict(robot=name, alive=name in self._alive, leaving=name in self._leaving)
                if got is not None:
                    rep, at = got
                    base.update(cores=rep.cores, speed=rep.speed, cpu_busy=rep.cpu_busy, runnable=rep.runnable,
                                ramps_running=rep.ramps_running, accepted_total=rep.accepted_total,
                                finished_total=rep.finished_total, blacklisted=list(rep.blacklisted),
                                cpu_per_core=list(rep.cpu_per_core), load_avg=rep.load_avg,
                                mem_free=rep.mem_free, bad_messages=rep.bad_messages, report_age=now - at,
                                sees=rep.sees, running=list(rep.running), links=list(rep.links),
                                learned=list(rep.learned), moves=rep.moves, moves_aborted=rep.moves_aborted,
                                node_cpu=rep.node_cpu, accelerators=list(rep.accelerators), battery=rep.battery,
                                low_battery=rep.low_battery, power=rep.power)
                rows.append(RobotStatus(**base))
        return TeamStatus(team=self.team, robots=rows)

    def pending(self) -> int:
        """How many of this client's programs have not finished yet."""
        with self._lock:
            return len(self._futures)

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
            futs = list(self._futures.values())
            self._futures.clear()
            self._timer_cv.notify_all()
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
        with _OPEN_LOCK:
            _OPEN.discard(self)

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
