"""What one node did over a run, for the simulator's results (``Node.statistics``)."""

from __future__ import annotations

import msgspec


class NodeStatistics(msgspec.Struct, frozen=True, kw_only=True):
    robot: str
    placements: int
    delivered: int
    discarded: int
    anomalies: int
    host_failures: int
    rejections: int
    refused: int
    accepted_total: int
    finished_total: int
    running: int
    active_programs: int
    blacklisted: list[str]
    reports_received: int
    #: program name -> work learned from completed runs (see Origin.work_estimate)
    learned_work: dict[str, float] = {}
    #: relocations after placement started, and those abandoned (the new
    #: host refused or failed; the old copy ran on)
    moves: int = 0
    moves_aborted: int = 0
