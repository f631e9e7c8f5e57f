"""Deadlines: a program's time limit, and what it does when no robot can keep it.

How this works: a program may carry one deadline (``Submit.deadline``,
absolute in the core's time, a finite number; ``check`` refuses anything
else). Its policy keeps to hosts expected to finish in time; when none is
(``Placement.late``), or the deadline has passed at a re-placement, its
``on_miss`` (one of ``ON_MISS``) decides in ``unmet``: "run" where it ends
soonest, "local" here, or "fail" at once (``error_kind`` "deadline").
Offered in time, placed or moved, a program tells its host how long it has
(``OffloadRequest.deadline_in``); the host turns it away as "late" if it or
a program it runs would miss (then it is placed at once elsewhere, or stays
where it runs); one run anyway is offered without it. Delivered after its
deadline, it is a miss (``late``: ``Deliver.missed_deadline``,
``Origin.deadline_misses``).

Rules: no clock (``now`` comes in), no I/O.
"""

from __future__ import annotations

import sys
from typing import Protocol

from ramps.core.events import Action, Note, Submit
from ramps.core.policy import Placement
from ramps.core.program import AutonomousProgram

#: what a program with a deadline may do when no robot is expected to meet
#: it (``Submit.on_miss``): run where it ends soonest, run here, or fail now
ON_MISS = ("run", "local", "fail")


class DeliveringOrigin(Protocol):
    """What ``unmet`` needs of ``ramps.core.origin.Origin``."""

    me: str

    def deliver(self, ap: AutonomousProgram, now: float, out: list[Action], *, ok: bool,
                value: bytes = b"", error: str = "", host: str = "", kind: str = "") -> None: ...


def check(sub: Submit) -> None:
    """Refuse (``ValueError``) a submission whose ``on_miss`` or deadline is not one."""
    if sub.on_miss not in ON_MISS:
        raise ValueError(f"program {sub.program_id!r}: on_miss is one of {', '.join(ON_MISS)}, got {sub.on_miss!r}")
    if sub.deadline is not None and not (type(sub.deadline) in (int, float)
                                         and abs(sub.deadline) <= sys.float_info.max):  # not NaN, inf, 10**400
        raise ValueError(f"program {sub.program_id!r}: a deadline must be a finite number, got {sub.deadline!r}")


def unmet(origin: DeliveringOrigin, ap: AutonomousProgram, placement: Placement, left: float, now: float,
          out: list[Action]) -> str | None:
    """No candidate is expected to finish ``ap`` within the ``left``
    seconds to its deadline: its ``on_miss`` says where it runs anyway
    (the policy's pick, or this robot), or it fails now (None)."""
    sub = ap.submit
    best = placement.expected_time
    at_best = f"{best:.2f} s at best (on {placement.host})" if best is not None else "too long"
    why = f"expected {at_best}, {max(0.0, left):.2f} s left to its deadline"
    if sub.on_miss == "fail":
        origin.deliver(ap, now, out, ok=False, kind="deadline", host=placement.host,
                       error=f"{sub.program} cannot meet its deadline: {why}")
        return None
    host = origin.me if sub.on_miss == "local" else placement.host
    out.append(Note(what="deadline_unmet", program_id=ap.program_id, robot=host, attempt=ap.made + 1,
                    detail=f"{why}; on_miss={sub.on_miss}"))
    return host


def late(sub: Submit, now: float, *, ok: bool, kind: str) -> str | None:
    """How a program delivered at ``now`` missed its deadline (None: it did
    not, or had none): refused as unmeetable, or a result that came late."""
    due = sub.deadline
    if due is None or not (kind == "deadline" or (ok and now > due)):
        return None
    return "unmeetable" if kind == "deadline" else f"{now - due:.3f} s late"
