"""Accelerators: a robot's GPUs (or any device a kind of program runs faster
on) as the cost model sees them.

How this works: a robot advertises each kind of accelerator it has (``cuda``,
say) with a number of slots and a speed: work units per second that one
program gets on one slot. A program declares the kind it can use and its
work there (``accelerator_work``, in the same units at speed 1), next to its
work on a CPU. Programs on one kind of accelerator share its slots as CPU
programs share cores (processor sharing, at most one slot each): with ``k``
programs already on ``count`` slots, a new one computes for
``work / speed * max(1, (k + 1) / count)`` seconds. A program on an
accelerator is not a CPU program: it is left out of the CPU counts, and the
core it may keep busy shows in the robot's measured run queue like the
robot's own software. Pure functions and plain data, no state.
"""

from __future__ import annotations

import msgspec

#: most kinds of accelerator one robot advertises
MAX_KINDS = 8


class Accelerator(msgspec.Struct, frozen=True, kw_only=True):
    """One kind of accelerator on a robot: ``count`` slots (devices, or
    programs one device runs at full speed side by side) of ``speed`` work
    units per second each."""

    kind: str
    count: int = 1
    speed: float = 1.0

    def __post_init__(self) -> None:
        if not self.kind or not self.kind.replace("-", "").replace("_", "").isalnum():
            raise ValueError(f"accelerator kind must be letters, digits, '-' or '_', got {self.kind!r}")
        if self.count < 1:
            raise ValueError(f"accelerator {self.kind!r}: count must be at least 1, got {self.count}")
        if not 0.0 < self.speed < float("inf"):
            raise ValueError(f"accelerator {self.kind!r}: speed must be positive, got {self.speed}")


def parse_accelerator(text: str) -> Accelerator:
    """``KIND[:COUNT[:SPEED]]`` (``cuda``, ``cuda:2``, ``cuda:1:20``) as an
    ``Accelerator``; ValueError naming the text otherwise."""
    parts = text.strip().split(":")
    if not 1 <= len(parts) <= 3 or not parts[0]:
        raise ValueError(f"accelerator {text!r}: expected KIND[:COUNT[:SPEED]], e.g. cuda:1:20")
    try:
        count = int(parts[1]) if len(parts) > 1 and parts[1] else 1
        speed = float(parts[2]) if len(parts) > 2 and parts[2] else 1.0
    except ValueError:
        raise ValueError(f"accelerator {text!r}: COUNT must be a whole number and SPEED a number, "
                         f"e.g. cuda:1:20") from None
    return Accelerator(kind=parts[0], count=count, speed=speed)


def accelerator_time(work: float, count: float, speed: float, programs: float) -> float:
    """Seconds a new program of ``work`` units computes on ``count`` slots of
    ``speed`` that already run ``programs`` programs (processor sharing)."""
    return work / speed * max(1.0, (programs + 1.0) / count)


def slot_share(count: float, programs: float) -> float:
    """Fraction of one slot each of ``programs`` programs gets."""
    if programs <= count:
        return 1.0
    return count / programs


def work_left(placed: list[tuple[float, float]], now: float, count: float, speed: float,
              programs: int) -> list[float]:
    """Work left at ``now`` in programs (work, started at) ``placed`` on
    ``count`` slots of ``speed`` that run ``programs`` programs in all (as
    many as since they started, processor sharing), at most ``programs`` of
    them, the largest. One whose work should be done by now is left out:
    still counted as running, it took more than its estimate, and how much
    more is not known (the caller prices it as it prices programs of
    unknown work)."""
    if programs <= 0:
        return []
    rate = speed * slot_share(count, programs)
    return sorted(x for work, at in placed if (x := work - (now - at) * rate) > 0.0)[-programs:]


def reported_left(listed: list[float], now: float, at: float, count: float, speed: float, running: int,
                  ended: list[tuple[float, float]]) -> list[float]:
    """Work left at ``now`` in the programs a host's report made at ``at``
    ``listed`` on ``count`` slots of ``speed`` (``AcceleratorSeen.remaining``),
    ``running`` programs on them then (processor sharing), less, for each
    program (work, started at) ``ended`` that the caller knows ended and the
    report still shows, the one nearest the work it had left by the same
    estimate. As in ``work_left``, one whose work should be done by now is
    left out, to be priced as one of unknown work."""
    rate = speed * slot_share(count, running)
    left = [x - (now - at) * rate for x in listed]
    for work, started in ended:
        if left:
            gone = work - (now - started) * rate
            left.remove(min(left, key=lambda x: abs(x - gone)))
    return sorted(x for x in left if x > 0.0)
