"""Whether a teammate's load report can be used at all: the physical
bounds every cost estimate relies on (``report_problem``). Pure functions."""

from __future__ import annotations

import math

from ramps.core.messages import MAX_CORES, MAX_LOAD, MAX_SPEED, MAX_WEIGHT, MIN_SPEED, MIN_WEIGHT, LoadReport

#: the speeds ``report_problem``'s quick check passes: within both bounds it checks
_SPEED_LOW, _SPEED_TOP = max(MIN_SPEED, 0.0), min(MAX_SPEED, MAX_LOAD)


def report_problem(report: LoadReport) -> str | None:
    """Why a teammate's report cannot be used, or None if it can. A report
    with zero cores or speed would make every cost estimate divide by zero,
    and so would a tiny speed over a huge run queue (their product underflows
    to 0.0): the bounds are those the wire schema declares.

    Every report a node hears or makes passes here: a sound one in a single
    chain of comparisons (a NaN or an infinity fails ``0 <= x <= MAX_LOAD``
    as surely as ``math.isfinite``), a faulty one through ``_problem`` for
    the words."""
    if (1 <= report.cores <= MAX_CORES and _SPEED_LOW <= report.speed <= _SPEED_TOP
            and 0 <= report.cpu_busy <= MAX_LOAD and 0 <= report.runnable <= MAX_LOAD
            and 0 <= report.ramps_avg <= MAX_LOAD and 0 <= report.window <= MAX_LOAD
            and MIN_WEIGHT <= report.program_weight <= MAX_WEIGHT
            and report.ramps_running >= 0 and report.accepted_total >= 0 and report.finished_total >= 0
            and (not report.accelerators or all(1 <= a.count <= MAX_CORES and MIN_SPEED <= a.speed <= MAX_SPEED
                                                 for a in report.accelerators))):
        return None
    return _problem(report)


def _problem(report: LoadReport) -> str | None:
    """``report_problem``'s words for a report that failed its quick check."""
    if not 1 <= report.cores <= MAX_CORES:
        return f"load report from {report.robot!r} claims {report.cores} cores"
    for name in ("speed", "cpu_busy", "runnable", "ramps_avg", "window"):
        value = getattr(report, name)
        if not math.isfinite(value) or not 0 <= value <= MAX_LOAD:
            return f"load report from {report.robot!r} has {name}={value!r}"
    if not MIN_SPEED <= report.speed <= MAX_SPEED:
        return f"load report from {report.robot!r} claims speed {report.speed!r}"
    if not MIN_WEIGHT <= report.program_weight <= MAX_WEIGHT:
        return f"load report from {report.robot!r} claims program weight {report.program_weight!r}"
    if report.ramps_running < 0 or report.accepted_total < 0 or report.finished_total < 0:
        return f"load report from {report.robot!r} has negative counters"
    for a in report.accelerators:
        if not (1 <= a.count <= MAX_CORES and MIN_SPEED <= a.speed <= MAX_SPEED):
            return f"load report from {report.robot!r} claims accelerator {a.kind!r} x{a.count} at speed {a.speed!r}"
    return None
