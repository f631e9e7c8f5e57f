"""What a simulation run produced: a record per program, the trace, and
the run's result (``ramps.sim.engine.simulate`` returns a ``SimResult``).
Plain data."""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from typing import Any

import msgspec

from ramps.core.statistics import NodeStatistics


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


def tally(records: Iterable[ProgramRecord], robots: list[str]) -> tuple[dict[str, int], int, int, int, int, int, int]:
    """What the records of a run add up to: completed programs per robot,
    completed, failed, lost, duplicated deliveries, programs with a
    deadline, deadlines missed (each record's ``missed_deadline`` set)."""
    dist = {n: 0 for n in robots}
    completed = failed = lost = dup = 0
    deadlines = misses = 0
    for rec in records:
        if rec.deadline is not None:
            deadlines += 1
            rec.missed_deadline = not (rec.ok and rec.delivered_at is not None
                                       and rec.delivered_at <= rec.deadline + 1e-9)
            misses += rec.missed_deadline
        if rec.deliveries:
            dup += rec.deliveries - 1
            if rec.ok:
                completed += 1
                if rec.host is not None:  # set with ok, at the delivery
                    dist[rec.host] = dist.get(rec.host, 0) + 1
            else:
                failed += 1
        elif not rec.error:
            lost += 1
    return dist, completed, failed, lost, dup, deadlines, misses


def running_where(robots: Mapping[str, Any], records: Mapping[str, ProgramRecord]) -> dict[str, int]:
    """Where each still-running program's current attempt runs now: the
    programs on each of the simulator's ``robots`` (``ramps.sim.engine._Robot``)."""
    counts = {n: 0 for n in robots}
    for name, r in robots.items():
        if not r.alive:
            continue
        for pid, attempt in r.cpu.jobs:
            origin = robots.get(records[pid].origin)
            ap = origin.node.origin.programs.get(pid) if origin else None
            if ap is not None and ap.attempt == attempt and ap.host == name:
                counts[name] += 1
    return counts
