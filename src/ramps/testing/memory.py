"""The real node driver over an in-memory network, a fake clock and in-process programs.

How this works: a ``MemoryBus`` joins several ``MemoryTransport`` (one per
node or client) in this process. A put is handed at once, synchronously, to
every subscriber whose key expression intersects the key (as bytes) (Zenoh's own
``zenoh.KeyExpr.intersects``), on every transport it can reach; each
transport counts what its subscribers heard, by key (``heard``). A ``get``
is answered at once by every queryable it reaches whose key intersects the
expression, then told done.
Liveliness follows Zenoh, whose routing tells a subscriber about a key, not
about each token: a key is alive for it (PUT) once a token of that key it can
reach is declared, and gone (DELETE) once the last such token is undeclared,
or its transport closed or ``kill()``-ed; a second token of a key that is alive
already (two nodes under one robot name) is not told, nor is its going. A new
liveliness subscriber with ``history`` hears the keys alive now. ``cut(name)``
isolates one transport (its teammates' tokens go for it and its tokens go for
them, nothing passes either way) and ``restore(name)`` joins it again (the
tokens come back), as a link that fails and reconnects.

``FakeClock`` is the shared time (``advance()`` moves it; ``sleep()`` too).
``MemoryPool`` stands for ``ramps.runtime.workers.WorkerPool``: it runs the
registered Python functions in this process when told (``complete()``), so a
test decides when a program ends. ``StillSampler`` stands for the load
sampler (an idle robot).

``MemoryTeam`` puts it together: real ``NodeRuntime`` objects (real driver,
real core) started with ``threaded=False``, and real clients (``connect()``); ``run(seconds)`` steps every
node and moves the clock to the earliest time one of them wants to wake,
never past it, so no node sees a stall unless a test makes one. Everything
is deterministic and takes milliseconds.
"""

from __future__ import annotations

import functools
from collections import Counter
from typing import Any, Callable

import msgspec

from ramps.runtime.registry import decode_args, resolve

__all__ = ["FakeClock", "MemoryBus", "MemoryPool", "MemoryTeam", "MemoryTransport", "StillSampler"]

_enc = msgspec.msgpack.Encoder()


@functools.lru_cache(maxsize=4096)
def intersects(a: str, b: str) -> bool:
    """Whether two key expressions intersect, as Zenoh decides it."""
    import zenoh

    return bool(zenoh.KeyExpr(a).intersects(zenoh.KeyExpr(b)))


class FakeClock:
    """A clock that moves only when told (``advance``, ``sleep``)."""

    def __init__(self, start: float = 1000.0, wall: float = 1.8e9) -> None:
        self.t = start
        self._wall = wall - start

    def monotonic(self) -> float:
        return self.t

    def time(self) -> float:
        return self.t + self._wall

    def sleep(self, seconds: float) -> None:
        self.t += max(0.0, seconds)

    def advance(self, seconds: float) -> None:
        self.t += seconds


class _Declared:
    def __init__(self, undeclare: Callable[[], None]) -> None:
        self._undeclare = undeclare
        self.live = True

    def undeclare(self) -> None:
        if self.live:
            self.live = False
            self._undeclare()


class _MemoryPublisher:
    def __init__(self, transport: "MemoryTransport", key: str, block: bool) -> None:
        self.t, self.key, self.block = transport, key, block

    def put(self, data: bytes) -> None:
        self.t.put(self.key, data, block=self.block)

    def matching(self) -> bool:
        return self.t.bus.matching(self.t, self.key)

    def undeclare(self) -> None:
        pass


class MemoryBus:
    """Transports of one process joined in memory (see the module's docstring)."""

    def __init__(self) -> None:
        self.transports: dict[str, MemoryTransport] = {}
        self._subs: list[tuple[MemoryTransport, str, Callable[[bytes], None]]] = []
        self._lsubs: list[_LivelinessSub] = []
        self._queryables: list[tuple[MemoryTransport, str, Callable[[], bytes | None]]] = []
        self._tokens: list[tuple[MemoryTransport, str]] = []
        self._cut: set[str] = set()
        #: (sender, receiver): data dropped that way only, liveliness kept (``split``)
        self._one_way: set[tuple[str, str]] = set()
        #: messages that reached no subscriber because a link was cut
        self.lost = 0

    def transport(self, name: str) -> "MemoryTransport":
        if name in self.transports and not self.transports[name].closed:
            raise ValueError(f"a transport named {name!r} is already on this bus")
        t = self.transports[name] = MemoryTransport(self, name)
        return t

    def reaches(self, a: "MemoryTransport", b: "MemoryTransport") -> bool:
        if a.closed or b.closed:
            return False
        return a is b or (a.name not in self._cut and b.name not in self._cut)

    # ------------------------------------------------------------ data
    def put(self, src: "MemoryTransport", key: str, data: bytes) -> None:
        delivered = False
        for t, expr, cb in list(self._subs):
            if intersects(expr, key) and (src.name, t.name) not in self._one_way:
                if self.reaches(src, t):
                    t.heard[key] += 1
                    cb(bytes(data))
                    delivered = True
        if not delivered and src.name in self._cut:
            self.lost += 1

    def matching(self, src: "MemoryTransport", key: str) -> bool:
        return any(self.reaches(src, t) and intersects(expr, key) for t, expr, _ in self._subs)

    def subscribe(self, t: "MemoryTransport", key: str, cb: Callable[[bytes], None]) -> _Declared:
        entry = (t, key, cb)
        self._subs.append(entry)
        return _Declared(lambda: self._drop(self._subs, entry))

    # ------------------------------------------------------------ queries
    def queryable(self, t: "MemoryTransport", key: str, answer: Callable[[], bytes | None]) -> _Declared:
        entry = (t, key, answer)
        self._queryables.append(entry)
        return _Declared(lambda: self._drop(self._queryables, entry))

    def get(self, src: "MemoryTransport", key: str, on_reply: Callable[[bytes], None],
            on_done: Callable[[], None]) -> None:
        for t, qkey, answer in list(self._queryables):
            if intersects(qkey, key) and self.reaches(src, t):
                data = answer()
                if data is not None:
                    src.heard[qkey] += 1
                    on_reply(bytes(data))
        on_done()

    # ------------------------------------------------------------ liveliness
    def _alive_for(self, sub: "_LivelinessSub") -> dict[str, None]:
        """The keys of the tokens a subscriber can reach now, in declaration order."""
        return dict.fromkeys(key for owner, key in self._tokens
                             if intersects(sub.expr, key) and self.reaches(owner, sub.t))

    def _sync(self, subs: "list[_LivelinessSub] | None" = None) -> None:
        """Tell each liveliness subscriber the keys that went (DELETE) and
        came (PUT) for it since it was last told."""
        for sub in list(self._lsubs) if subs is None else subs:
            alive = self._alive_for(sub)
            gone, new = [k for k in sub.told if k not in alive], [k for k in alive if k not in sub.told]
            sub.told = alive
            for key in gone:
                sub.cb(key, False)
            for key in new:
                sub.cb(key, True)

    def declare_token(self, t: "MemoryTransport", key: str) -> _Declared:
        token = (t, key)
        self._tokens.append(token)
        self._sync()

        def undeclare() -> None:
            self._tokens.remove(token)
            self._sync()

        return _Declared(undeclare)

    def subscribe_liveliness(self, t: "MemoryTransport", key: str, cb: Callable[[str, bool], None],
                             history: bool) -> _Declared:
        sub = _LivelinessSub(t, key, cb)
        self._lsubs.append(sub)
        if history:
            self._sync([sub])
        else:  # it hears what comes from now on, and the going of what is there
            sub.told = self._alive_for(sub)
        return _Declared(lambda: self._drop(self._lsubs, sub))

    @staticmethod
    def _drop(entries: list, entry: object) -> None:
        if entry in entries:
            entries.remove(entry)

    # ------------------------------------------------------------ faults
    def cut(self, name: str) -> None:
        """Isolate one transport: its links to every other one fail."""
        if name in self._cut:
            return
        self._cut.add(name)
        self._sync()  # it hears its teammates go, and they hear it go

    def split(self, sender: str, receiver: str) -> None:
        """What ``sender`` publishes no longer reaches ``receiver``; tokens stay (a split
        Zenoh session, eclipse-zenoh/zenoh#2806). ``restore(sender)`` ends it."""
        self._one_way.add((sender, receiver))

    def restore(self, name: str) -> None:
        """Join a cut transport again: the tokens on both sides come back."""
        self._one_way = {pair for pair in self._one_way if pair[0] != name}
        if name not in self._cut:
            return
        self._cut.discard(name)
        self._sync()

    def kill(self, name: str) -> None:
        """The process behind a transport dies: it hears nothing more, and its
        teammates hear its tokens go."""
        t = self.transports[name]
        self._subs = [e for e in self._subs if e[0] is not t]
        self._lsubs = [e for e in self._lsubs if e.t is not t]
        self._queryables = [e for e in self._queryables if e[0] is not t]
        t.close()


class _LivelinessSub:
    """A liveliness subscriber on a ``MemoryBus``, with the keys it was told are alive."""

    __slots__ = ("t", "expr", "cb", "told")

    def __init__(self, t: "MemoryTransport", expr: str, cb: Callable[[str, bool], None]) -> None:
        self.t, self.expr, self.cb = t, expr, cb
        self.told: dict[str, None] = {}


class MemoryTransport:
    """A ``ramps.runtime.transport.Transport`` on a ``MemoryBus``."""

    def __init__(self, bus: MemoryBus, name: str) -> None:
        self.bus, self.name = bus, name
        self.closed = False
        self._declared: list[_Declared] = []
        #: every put from this transport: (key, bytes, block)
        self.sent: list[tuple[str, bytes, bool]] = []
        #: samples and replies its subscribers and queries heard, by key
        self.heard: Counter[str] = Counter()
        #: the expressions it queried (``get``)
        self.queried: list[str] = []

    def _keep(self, d: _Declared) -> _Declared:
        self._declared.append(d)
        return d

    def _check(self) -> None:
        if self.closed:
            from ramps.errors import TransportError

            raise TransportError(f"transport {self.name!r} is closed")

    def subscribe(self, key: str, callback: Callable[[bytes], None]) -> _Declared:
        self._check()
        return self._keep(self.bus.subscribe(self, key, callback))

    def subscribe_liveliness(self, key: str, callback: Callable[[str, bool], None], *,
                             history: bool = True) -> _Declared:
        self._check()
        return self._keep(self.bus.subscribe_liveliness(self, key, callback, history))

    def declare_token(self, key: str) -> _Declared:
        self._check()
        return self._keep(self.bus.declare_token(self, key))

    def publisher(self, key: str, *, block: bool = False) -> _MemoryPublisher:
        self._check()
        return _MemoryPublisher(self, key, block)

    def put(self, key: str, data: bytes, *, block: bool = False) -> None:
        if self.closed:
            return
        self.sent.append((key, bytes(data), block))
        self.bus.put(self, key, data)

    def queryable(self, key: str, answer: Callable[[], bytes | None]) -> _Declared:
        self._check()
        return self._keep(self.bus.queryable(self, key, answer))

    def get(self, key: str, on_reply: Callable[[bytes], None], on_done: Callable[[], None], *,
            timeout: float) -> None:
        if self.closed:
            on_done()
            return
        self.queried.append(key)
        self.bus.get(self, key, on_reply, on_done)

    def locators(self) -> list[str]:
        return [f"memory/{self.name}"]

    def peers(self) -> list[str]:
        return [n for n, t in self.bus.transports.items() if t is not self and self.bus.reaches(self, t)]

    def close(self) -> None:
        if self.closed:
            return
        for d in reversed(self._declared):  # tokens go (DELETE) while the transport still reaches its subscribers
            d.undeclare()
        self.closed = True


class MemoryPool:
    """In-process stand-in for ``WorkerPool``: ``run`` queues a program,
    ``complete()`` runs the queued ones (the registered Python functions) and
    reports each as a worker would. Nothing runs until a test says so."""

    def __init__(self, size: int, targets: dict[str, str], on_finished: Callable[..., None], *, nice: int = 0,
                 on_progress: Callable[..., None] | None = None,
                 on_checkpoint: Callable[..., None] | None = None, core_share: float = 1.0,
                 bundled: bool = True) -> None:
        self.size, self.targets, self.on_finished = size, targets, on_finished
        self.jobs: dict[tuple[str, int], tuple[str, bytes]] = {}
        self.started = self.stopped = False
        #: every program started: (key, program), and the accelerator each was given
        self.ran: list[tuple[tuple[str, int], str]] = []
        self.granted: dict[tuple[str, int], dict[str, Any] | None] = {}

    def start(self) -> None:
        self.started = True

    def stop(self) -> None:
        self.stopped = True
        self.jobs.clear()

    def run(self, key: tuple[str, int], program: str, args: bytes, resume: bytes | None = None,
            accelerator: dict[str, Any] | None = None) -> None:
        if not self.stopped:
            self.jobs[key] = (program, args)
            self.ran.append((key, program))
            self.granted[key] = accelerator

    def cancel(self, key: tuple[str, int]) -> None:
        self.jobs.pop(key, None)

    def busy(self) -> int:
        return min(len(self.jobs), self.size)

    def queued(self) -> int:
        return max(0, len(self.jobs) - self.size)

    def complete(self) -> int:
        """Run every queued program now; how many."""
        jobs, self.jobs = self.jobs, {}
        for key, (program, args) in jobs.items():
            try:
                value = resolve(self.targets[program])(**decode_args(args))
                self.on_finished(key, True, _enc.encode(value), "", False, None)
            except Exception as exc:
                self.on_finished(key, False, b"", f"{type(exc).__name__}: {exc}", False, None)
        return len(jobs)


class StillSampler:
    """In-process stand-in for ``LoadSampler``: an idle robot but for the
    programs of its pool."""

    def __init__(self, ramps_count: Callable[[], int], **_: Any) -> None:
        self.count = ramps_count

    def start(self) -> None:
        pass

    def stop(self) -> None:
        pass

    def averages(self) -> tuple[float, float, float]:
        n = float(self.count())
        return n, n, n

    def extras(self) -> tuple[list[float], float, int]:
        return [], 0.0, 8 << 30


class MemoryTeam:
    """Real ``NodeRuntime`` nodes on one ``MemoryBus`` and ``FakeClock``,
    stepped by hand (see the module's docstring)."""

    def __init__(self, robots: dict[str, tuple[int, float]], *, team: str = "mem",
                 settings: dict[str, Any] | None = None, programs: list[str] | None = None) -> None:
        from ramps.runtime.settings import load_settings

        self.bus = MemoryBus()
        self.clock = FakeClock()
        self.team = team
        self.nodes: dict[str, Any] = {}
        self.pools: dict[str, MemoryPool] = {}
        self._settings = settings or {}
        self._programs = programs or []
        self._load_settings = load_settings
        for i, (name, (cores, speed)) in enumerate(robots.items()):
            self.add(name, cores=cores, speed=speed, seed=i)

    def add(self, name: str, *, cores: int = 2, speed: float = 1.0, seed: int = 0) -> Any:
        """Start one more node (real driver, real core) on the bus."""
        from ramps.runtime.node import NodeRuntime

        flags = {"robot": name, "team": self.team, "cores": cores, "speed": speed, "programs": self._programs,
                 "battery_sysfs": False, **self._settings}  # not the battery of the machine the tests run on
        s = self._load_settings(flags=flags, environ={})

        def pool(*a: Any, **kw: Any) -> Any:
            p = self.pools[name] = self.make_pool(*a, **kw)
            return p

        rt = NodeRuntime(s, transport=self.bus.transport(name), clock=self.clock, worker_pool=pool,
                         load_sampler=StillSampler, incarnation=seed + 1)
        rt.start(threaded=False)
        self.nodes[name] = rt
        return rt

    def make_pool(self, *a: Any, **kw: Any) -> Any:
        """The worker pool of a node this team starts (``NodeRuntime``'s
        ``worker_pool`` arguments): in-process programs, a ``MemoryPool``. A
        subclass may run real worker processes instead."""
        return MemoryPool(*a, **kw)

    def connect(self, robot: str, name: str = "app") -> Any:
        """A real client (``ramps.runtime.client.Team``, what ``ramps.connect()``
        returns) on the bus, submitting to ``robot``'s node. Its futures
        resolve as ``run()`` moves the team; ``close()`` it at the end."""
        from ramps.runtime.client import Team
        from ramps.runtime.settings import load_settings

        s = load_settings(flags={"team": self.team}, environ={}, default_robot=False)
        return Team(s, robot=robot, timeout=1.0, transport=self.bus.transport(name), clock=self.clock)

    def step(self) -> None:
        """One round of every running node, until none has anything queued."""
        for _ in range(100):
            for rt in list(self.nodes.values()):
                if rt.transport is not None:
                    rt.step()
            if all(rt._q.empty() and not rt.intake.later for rt in self.nodes.values() if rt.transport is not None):
                return

    def run(self, seconds: float, *, complete: bool = True, until: Callable[[], bool] | None = None) -> None:
        """Step the team for ``seconds`` of fake time: the clock moves to the
        earliest time a node wants to wake (never past it). ``complete``:
        programs queued on each pool run at each round; ``until``: stop early
        once it is true."""
        end = self.clock.t + seconds
        while True:
            self.step()
            if complete:
                for name, pool in self.pools.items():
                    if self.nodes[name].transport is not None and pool.jobs:
                        pool.complete()
                        self.step()
            if until is not None and until():
                return
            live = [rt for rt in self.nodes.values() if rt.transport is not None]
            wake = min((rt.next_wake() for rt in live), default=end)
            if self.clock.t >= end:
                return
            self.clock.t = min(end, max(wake, self.clock.t + 1e-3))

    def stop(self, name: str) -> None:
        """Shut one node down cleanly (it hands its programs back)."""
        self.nodes[name].stop()

    def kill(self, name: str) -> None:
        """One node's process dies at once (SIGKILL): its teammates hear its
        liveliness go, its programs die with it, and whatever it had written
        (its durable record) stays as it was. ``add(name, seed=...)`` with
        another seed starts it again, as a new incarnation."""
        rt = self.nodes[name]
        self.bus.kill(name)
        self.pools[name].jobs.clear()
        rt.transport = None
        rt._stopped.set()  # nothing of it runs any more, stop() included
        if rt.store is not None:
            rt.store.close()
            rt.store = None

    def close(self) -> None:
        for rt in self.nodes.values():
            rt.stop()
