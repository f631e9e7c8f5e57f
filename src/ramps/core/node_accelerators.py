"""What a robot's load reports say of its accelerators.

How this works: ``accelerators_seen`` lists, for each kind of accelerator
the executor has, its slots, speed and programs on it, with what the driver
last measured of it (memory, utilisation) and the work each program there
has left. ``ramps.core.node.Node`` puts the list in every report it makes.
"""

from __future__ import annotations

from ramps.core.executor import Executor
from ramps.core.messages import AcceleratorSeen


def accelerators_seen(ex: Executor, measured: dict[str, tuple[int, int, float | None]],
                      now: float) -> list[AcceleratorSeen]:
    """The executor ``ex``'s accelerators as a report lists them at ``now``
    (``measured``: memory total, memory free and utilisation of each kind)."""
    if not ex.accelerators:
        return []
    out = []
    for kind, a in ex.accelerators.items():
        total, free, util = measured.get(kind, (0, 0, None))
        on_it = ex.on_accelerators[kind]
        out.append(AcceleratorSeen(kind, a.count, a.speed, on_it, total, free, util,
                                   ex.remaining(now, kind) if on_it else []))
    return out
