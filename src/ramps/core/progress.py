"""What a program's live copies say of themselves: how far they are, and their saved state.

How this works: a host passes on what a running program reports
(``ProgramProgress``, a fraction of the whole program) and the state it
saves (``ProgramCheckpoint``). Both are advisory: they change no state of
the program's state machine. The origin hands over only those of a copy
whose result it still wants. The current attempt's fraction becomes the
origin's estimate of the work done (``AutonomousProgram.done``), counted
from where the attempt resumed, which relocation reads; the latest
checkpoint is kept (one behind the state held already is dropped) so a
restart after a move or a failure resumes from it (``ramps.core.placing``).

Rules: functions of one program; no clock (``now`` comes in), no I/O.
"""

from __future__ import annotations

from ramps.core.events import Action, Note, Progress
from ramps.core.messages import ProgramCheckpoint, ProgramProgress
from ramps.core.program import AutonomousProgram


def on_progress(ap: AutonomousProgram, msg: ProgramProgress, now: float, out: list[Action]) -> None:
    """A wanted copy of ``ap`` says how far it is: pass it on."""
    if msg.attempt == ap.attempt:
        _done_at(ap, msg.fraction, now)
    out.append(Progress(program_id=msg.program_id, host=msg.host, attempt=msg.attempt,
                        fraction=msg.fraction, detail=msg.detail))


def on_checkpoint(ap: AutonomousProgram, msg: ProgramCheckpoint, now: float, out: list[Action]) -> bool:
    """A wanted copy of ``ap`` saved its state: keep the latest. Whether it was kept."""
    fraction = msg.fraction
    if fraction is not None and ap.checkpoint is not None and fraction < ap.checkpoint_fraction:
        return False  # an older copy, behind the state we already hold
    if fraction is None:  # the program says nothing of how far it is: assume the work is all ahead
        fraction = (ap.resumed_from or 0.0) if msg.attempt == ap.attempt else 0.0
    ap.checkpoint = msg.state
    ap.checkpoint_fraction = fraction
    if msg.attempt == ap.attempt:
        _done_at(ap, fraction, now)
    out.append(Note(what="checkpoint", program_id=ap.program_id, robot=msg.host, attempt=msg.attempt,
                    detail=f"{len(msg.state)} bytes at {fraction:.3f}"))
    return True


def _done_at(ap: AutonomousProgram, fraction: float, now: float) -> None:
    """The current attempt says it is ``fraction`` of the whole program
    through: set the origin's estimate of the work it has done."""
    base = ap.resumed_from or 0.0
    if base < 1.0:
        ap.done = min(ap.work, max(0.0, (fraction - base) / (1.0 - base) * ap.work))
        ap.done_at = now
