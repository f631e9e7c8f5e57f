"""The state a node's driver shares between its parts, declared once.

How this works: ``NodeRuntime`` (``ramps.runtime.node``) is its lifecycle
and loop plus three parts, ``Inbound`` (``node_inbound``), ``ClientAnswers``
(``node_clients``) and ``Outbound`` (``node_outbound``), each a base of it
and of ``DriverState`` here. ``DriverState`` holds no value and runs
nothing: it declares, with their types, the attributes the parts read and
write (``NodeRuntime.__init__`` and ``start`` set them) and, for the type
checker only, the methods one part calls on another, so that mypy checks
each part against the others. ``node``, ``transport``, ``metrics`` and
``store`` are None before ``start`` (the last two also when not asked
for): the parts run on the driver thread, after ``start``, and narrow them.
``WorkerPoolLike`` and ``SamplerLike`` are what the driver uses of its worker
pool and load sampler (``WorkerPool``/``LoadSampler`` or the in-memory
ones of ``ramps.testing.memory``).
"""

from __future__ import annotations

import queue
from collections import deque
from typing import TYPE_CHECKING, Any, Callable, Protocol

if TYPE_CHECKING:
    from cryptography import x509

    from ramps.core.durable import OriginRecord
    from ramps.core.events import Action, Deliver, Note
    from ramps.core.messages import LoadReport, SubmitProgram
    from ramps.core.node import Node
    from ramps.runtime.accelerators import AcceleratorProbe
    from ramps.runtime.bulk import OrderedSender
    from ramps.runtime.metrics import NodeMetrics
    from ramps.runtime.node_awake import AwakeClock
    from ramps.runtime.node_robot import RobotMeasure
    from ramps.runtime.node_team import Membership
    from ramps.runtime.node_trace import NodeTrace
    from ramps.runtime.registry import Registry
    from ramps.runtime.revocation import RevocationList
    from ramps.runtime.settings import NodeSettings
    from ramps.runtime.store import OriginStore
    from ramps.runtime.transport import Clock, Publisher, Transport

#: a running program: (program id, attempt)
Key = tuple[str, int]
#: a client's request: (client, request id)
RequestKey = tuple[str, int]


class WorkerPoolLike(Protocol):
    """What the driver uses of its worker pool (``ramps.runtime.workers.WorkerPool``)."""

    def start(self) -> None: ...

    def stop(self) -> None: ...

    def run(self, key: Key, program: str, args: bytes, resume: bytes | None = None,
            accelerator: dict[str, Any] | None = None) -> None: ...

    def cancel(self, key: Key) -> None: ...

    def busy(self) -> int: ...

    def queued(self) -> int: ...


class SamplerLike(Protocol):
    """What the driver uses of its load sampler (``ramps.runtime.measure.LoadSampler``)."""

    def start(self) -> None: ...

    def stop(self) -> None: ...

    def averages(self) -> tuple[float, float, float]: ...

    def extras(self) -> tuple[list[float], float, int]: ...


class DriverState:
    """The attributes and methods the parts of ``NodeRuntime`` share (declarations only)."""

    # ------------------------------------------------ set by __init__
    s: NodeSettings
    clock: Clock
    robot: str
    team: str
    registry: Registry
    on_note: Callable[[Note], None] | None
    #: the driver's queue: (kind, ...) items (``Inbound._handle``)
    _q: queue.SimpleQueue[tuple[Any, ...]]
    #: client requests: program id -> request, request -> program id, answered -> outcome sent
    _clients: dict[str, RequestKey]
    _requests: dict[RequestKey, str]
    _answered: dict[RequestKey, bytes | None]
    _kept_outcomes: deque[RequestKey]
    _kept_bytes: int
    _progress: dict[str, tuple[float, str]]
    _seq: int
    _outcomes_ready: dict[str, bytes]
    #: the durable record last written of each program not delivered yet
    _recorded: dict[str, OriginRecord]
    #: messages waiting for their receiver: (key, bytes, monotonic deadline, block)
    _held_outcomes: list[tuple[str, bytes, float, bool]]
    #: clients' updates waiting for their moment: program id -> [core time due, state, host, attempt]
    _held_updates: dict[str, list[Any]]
    _pubs: dict[str, Publisher]
    _update_pubs: dict[str, Publisher]
    _bulk: OrderedSender
    bad_messages: int
    overflow: int
    _sees: frozenset[str]
    _backlog_bytes: int
    _drop_logged_at: float
    _drops_unlogged: int
    trace: NodeTrace
    transport: Transport | None
    node: Node | None
    membership: Membership
    awake: AwakeClock
    measured: RobotMeasure
    _held_lost: dict[str, float]
    revocations: RevocationList | None
    _revoked: frozenset[str]
    _ca_cert: x509.Certificate | None
    _revocation_file: str | None
    _republish_at: float
    revoked_dropped: int
    revoked_self: bool
    name_taken: str
    metrics: NodeMetrics | None
    store: OriginStore | None
    restored: int
    _last_report: LoadReport | None

    # ------------------------------------------------ set by start
    cores: int
    speed: float
    incarnation: int
    load_scope: str
    pool: WorkerPoolLike
    sampler: SamplerLike
    accel: AcceleratorProbe
    _misdeclared_warned: set[str]
    endpoints_of: dict[int, list[str]]

    if TYPE_CHECKING:
        # what one part calls on another
        def _clock(self) -> float: ...  # NodeRuntime

        def endpoints(self) -> list[str]: ...  # NodeRuntime

        def _republish(self, now: float) -> None: ...  # Inbound

        def _client_submit(self, m: SubmitProgram, now: float) -> list[Action]: ...  # ClientAnswers

        def _persist(self, actions: list[Action]) -> None: ...

        def _tell_client(self, pid: str, *, ok: bool, value: bytes = b"", error: str = "", kind: str = "",
                         host: str = "", attempts: int = 0, moves: int = 0, resumed_from: float | None = None,
                         missed_deadline: bool = False) -> list[Action]: ...

        def _update_client(self, pid: str, state: str, host: str, attempt: int) -> None: ...

        def _flush_updates(self, now: float) -> None: ...

        def _flush_outcomes(self) -> None: ...

        def _held_due(self, now: float) -> float: ...  # Outbound

        def _flush_held(self, now: float) -> None: ...

        def _put(self, key: str, data: bytes, *, block: bool = False) -> None: ...

        def _publisher(self, key: str, block: bool, pubs: dict[str, Publisher] | None = None) -> Publisher: ...

        def _as_told(self, a: Deliver) -> Deliver: ...
