"""What completed runs say of a program's work: the origin's learned estimates.

How this works: a host tells the origin the work a finished run took
(``ProgramResult.work_done``): on a CPU, its CPU seconds at the host's
speed; on an accelerator, the work processor sharing of the host's slots
did for it over its wall time (``ramps.core.executor``). The origin keeps
each program's latest ``LEARN_RUNS`` runs as work per unit it declared,
apart for each device: a program's runs on a CPU under its name, its runs
on an accelerator under ``"NAME on KIND"`` against its declared
accelerator work (what it takes on a GPU says nothing of its work on a
CPU). Placement uses the median times a call's declaration, so a caller
that declares bigger calls bigger keeps the sizes apart. Plain state, no
clock: ``Learning`` is a part of ``ramps.core.origin.Origin``.
"""

from __future__ import annotations

import math
import statistics
from collections import deque
from collections.abc import Sequence

from ramps.core.events import Action, Note, Submit
from ramps.core.program import AutonomousProgram
from ramps.core.speed import MIN_RUN_WORK

#: how many of a program's latest runs its learned work is the median of
LEARN_RUNS = 8
#: a call whose measured work is more than this many times its declaration,
#: or less than its inverse, is flagged (``Note(what="misdeclared")``)
MISDECLARED = 4.0
#: a resumed attempt that ran less than this fraction of its program says
#: nothing of the whole program's work
LEARN_MIN_PART = 0.2


def learned_name(program: str, accelerator: str = "") -> str:
    """The name a program's runs on ``accelerator`` ("" = a CPU) are learned under."""
    return f"{program} on {accelerator}" if accelerator else program


class Learning:
    """The learned work of an origin's programs (see the module docstring)."""

    def __init__(self) -> None:
        #: work each program took in its latest runs per unit it declared,
        #: by ``learned_name``
        self._learned: dict[str, deque[float]] = {}
        #: the declaration of each one's latest learned run (for status)
        self._declared: dict[str, float] = {}

    def _learn(self, ap: AutonomousProgram, attempt: int, host: str, work_done: float, out: list[Action]) -> None:
        """What a completed run says of its program's work.

        Only the attempt that delivered as the program's current one counts
        (its start point is known): one resumed from a checkpoint at
        fraction ``f`` did ``1 - f`` of the program, so the whole took
        ``work_done / (1 - f)``, and one that did less than
        ``LEARN_MIN_PART`` says nothing. A run shorter than ``MIN_RUN_WORK``
        is not learned from either: too short to measure, and a caller's
        warm-up calls that return at once must not make its real calls of
        the same declaration look free. A call that took more than
        ``MISDECLARED`` times its declaration, or less than its inverse, is
        flagged with a ``misdeclared`` note (trace, log, metric) whether it
        is learned from or not. A run on an accelerator (``ap.accelerator``)
        is measured against the declared accelerator work."""
        if attempt != ap.attempt or not (math.isfinite(work_done) and work_done >= 0.0):
            return
        part = 1.0 - (ap.resumed_from or 0.0)
        if part < LEARN_MIN_PART:
            return
        sub, kind = ap.submit, ap.accelerator
        whole, declared = work_done / part, (sub.accelerator_work or sub.work) if kind else sub.work
        name = learned_name(sub.program, kind)
        if declared > 0 and max(whole, declared) >= MIN_RUN_WORK \
                and not 1.0 / MISDECLARED <= whole / declared <= MISDECLARED:
            out.append(Note(what="misdeclared", program_id=ap.program_id, robot=host, attempt=attempt,
                            detail=f"{name} declared {declared:.4g} work units, took {whole:.4g} "
                                   f"({whole / declared:.3g}x)"))
        if whole < MIN_RUN_WORK:
            return
        runs = self._learned.setdefault(name, deque(maxlen=LEARN_RUNS))
        runs.append(whole / declared if declared > 0 else whole)
        self._declared[name] = declared

    def work_estimate(self, sub: Submit) -> float:
        """The work a program will take on a CPU: its declaration times the
        median of what its latest runs took per declared unit (robust to one
        odd host), or its declaration before any ran."""
        return self._estimate(sub.program, sub.work)

    def accelerator_work_estimate(self, sub: Submit) -> float:
        """The work a program will take on its accelerator, learned as
        ``work_estimate`` from its runs there (its declared accelerator work,
        else its work, before any ran)."""
        return self._estimate(learned_name(sub.program, sub.accelerator), sub.accelerator_work or sub.work)

    def _estimate(self, name: str, declared: float) -> float:
        runs = self._learned.get(name)
        if not runs:
            return declared
        return statistics.median(runs) * (declared if declared > 0 else 1.0)

    def learned_runs(self, program: str) -> Sequence[float]:
        """The work each of ``program``'s latest learned runs took per unit it
        declared, oldest first (none before any ran)."""
        return self._learned.get(program, ())

    def learned_work(self) -> dict[str, float]:
        """Learned name -> the work placements now assume for a call declared
        like its latest run (learned ones only)."""
        return {name: statistics.median(runs) * (self._declared.get(name, 0.0) or 1.0)
                for name, runs in self._learned.items() if runs}
