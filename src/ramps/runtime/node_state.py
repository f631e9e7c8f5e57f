"""The state a node's driver shares with its input mixin, declared once.

How this works: ``NodeRuntime`` (``ramps.runtime.node``) is its lifecycle
and loop, a mixin, ``Inbound`` (``node_inbound``), base of it and of
``DriverState`` here, and the composed parts it holds, each with its own
state (``Outbound``, ``ClientAnswers``, ``LoadReports``, ``Outbox``,
``WireIntake``, ``AwakeClock``, ``RobotMeasure``, ``Membership``,
``SameName``, ``Revoked``, ``NodeTrace``: the ``node_*`` modules).
``DriverState`` holds no value and runs nothing: it declares, with their
types, the attributes of the driver (``NodeRuntime.__init__`` and
``start`` set them) and, for the type checker only, the methods the mixin
calls on it, so that mypy checks the mixin against the driver and the
driver against the protocols its parts see it through. ``node``,
``transport``, ``metrics`` and ``store`` are None before ``start`` (the
last two also when not asked for): the mixin runs on the driver thread,
after ``start``, and narrows them. What the driver uses of its worker pool
and load sampler is declared in ``node_seams``.
"""

from __future__ import annotations

import queue
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:

    from ramps.core.node import Node
    from ramps.runtime.accelerators import AcceleratorProbe
    from ramps.runtime.metrics import NodeMetrics
    from ramps.runtime.node_awake import AwakeClock, HeldLosses
    from ramps.runtime.node_intake import WireIntake
    from ramps.runtime.node_outbox import Outbox
    from ramps.runtime.node_name import SameName
    from ramps.runtime.node_reports import LoadReports
    from ramps.runtime.node_revoked import Revoked
    from ramps.runtime.node_robot import RobotMeasure
    from ramps.runtime.node_seams import SamplerLike, WorkerPoolLike
    from ramps.runtime.node_clients import ClientAnswers
    from ramps.runtime.node_team import Membership
    from ramps.runtime.node_trace import NodeTrace
    from ramps.runtime.registry import Registry
    from ramps.runtime.settings import NodeSettings
    from ramps.runtime.store import OriginStore
    from ramps.runtime.transport import Clock, Transport

class DriverState:
    """The attributes of ``NodeRuntime`` and what ``Inbound`` calls on it (declarations only)."""

    # ------------------------------------------------ set by __init__
    s: NodeSettings
    clock: Clock
    robot: str
    team: str
    registry: Registry
    #: the driver's queue: (kind, ...) items (``Inbound._handle``)
    _q: queue.SimpleQueue[tuple[Any, ...]]
    outbox: Outbox
    intake: WireIntake
    trace: NodeTrace
    transport: Transport | None
    node: Node | None
    membership: Membership
    awake: AwakeClock
    measured: RobotMeasure
    clients: ClientAnswers
    held_lost: HeldLosses
    revoked: Revoked
    same_name: SameName
    metrics: NodeMetrics | None
    store: OriginStore | None
    restored: int
    reports: LoadReports

    # ------------------------------------------------ set by start
    cores: int
    speed: float
    incarnation: int
    load_scope: str
    pool: WorkerPoolLike
    sampler: SamplerLike
    accel: AcceleratorProbe

    if TYPE_CHECKING:
        # what Inbound calls on the driver
        def endpoints(self) -> list[str]: ...  # NodeRuntime
