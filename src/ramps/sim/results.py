"""What a simulation run produced: a record per program, the trace, and
the run's result (``ramps.sim.engine.simulate`` returns a ``SimResult``).
Plain data."""

from __future__ import annotations

import msgspec

from ramps.core.node import NodeStatistics


class ProgramRecord(msgspec.Struct, kw_only=True):
    program_id: str
    origin: str
    submitted_at: float
    delivered_at: float | None = None
    host: str | None = None
    ok: bool | None = None
    attempts: int = 0
    error: str = ""
    deliveries: int = 0
    #: relocations after placement, and the progress the last attempt resumed from
    moves: int = 0
    resumed_from: float | None = None
    #: when its result was wanted (virtual time; None: no deadline), and
    #: whether it missed it: not delivered with a result by then
    deadline: float | None = None
    missed_deadline: bool = False


class TraceEntry(msgspec.Struct, frozen=True, array_like=True):
    t: float
    robot: str
    what: str
    program_id: str
    other: str
    attempt: int
    detail: str


class SimResult(msgspec.Struct, kw_only=True):
    scenario: str
    policy: str
    seed: int
    robots: list[str]
    #: delivered programs per robot that ran them (the paper's distribution)
    distribution: dict[str, int]
    #: seconds from the first submission to the last delivery
    makespan: float
    completed: int
    failed: int
    #: programs of a surviving origin never delivered / delivered more than once
    lost: int
    duplicated: int
    programs: list[ProgramRecord]
    statistics: list[NodeStatistics]
    snapshots: dict[str, dict[str, int]]
    events: int
    messages_sent: int
    messages_dropped: int
    end_time: float
    wall_seconds: float
    trace: list[TraceEntry] = []
    #: programs with a deadline, and those that missed it (late, failed or lost)
    deadlines: int = 0
    deadline_misses: int = 0
    #: joules each robot used (its busy core-seconds times its power, 1 W
    #: where the scenario gives none), and the charge left in each robot
    #: with a battery (``ramps.sim.battery``)
    energy: dict[str, float] = {}
    charge: dict[str, float] = {}
