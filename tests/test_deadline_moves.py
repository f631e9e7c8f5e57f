"""A move that the new host turns away as "late" (taking the program would
make a program there miss its deadline) leaves the program where it runs
and costs it none of its ``relocate_max_moves``: what the host protects ends
by its deadline, and a later check may move the program there or elsewhere
(docs/lab/2026-11-27-accelerators-deadlines-gap.md, deadlines-10)."""

from __future__ import annotations

import pytest

from ramps.core.config import RampsConfig
from ramps.core.events import Received
from ramps.core.messages import OffloadAccepted, OffloadRejected
from ramps.core.program import ProgramState
from corehelpers import Team, submit


def _move_refused(reason: str) -> Team:
    """``p`` runs on a host that becomes loaded, a move to the other host
    is offered, and that host answers ``reason`` (its acceptance held)."""
    team = Team({"o": (1, 1.0), "a": (4, 1.0), "b": (4, 1.0)}, config=RampsConfig())
    team.nodes["o"].executor.background = 10.0
    team.publish()
    submit(team, "p", work=60.0)
    team.deliver()
    first = team.program("p").host
    other = "b" if first == "a" else "a"
    team.advance(1.0)
    team.nodes[first].executor.background = 8.0
    team.publish()
    held = lambda s, to, m: isinstance(m, OffloadAccepted) and s == other  # noqa: E731
    for t in range(2, 10):
        team.advance(float(t), hold=held)
        team.publish()
        if team.program("p").state is ProgramState.MOVING:
            break
    ap = team.program("p")
    assert ap.state is ProgramState.MOVING and ap.moves == 1
    team.held.clear()
    team.handle("o", Received(sender=other, msg=OffloadRejected(
        program_id="p", attempt=ap.attempt, host=other, reason=reason, permanent=False, detail="")))
    assert team.program("p").state is ProgramState.RUNNING and team.program("p").host == first
    return team


@pytest.mark.parametrize(("reason", "moves"), [("late", 0), ("busy", 1)])
def test_a_move_refused_as_late_costs_no_move(reason: str, moves: int) -> None:
    team = _move_refused(reason)
    assert team.notes("move_aborted")
    assert team.program("p").moves == moves
