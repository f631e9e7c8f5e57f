"""The bytes an origin's offers to a host still carry: ``placing.queued_bytes``
walks the origin's recent offers to that host (``Origin.offered``) and gives
the same number as the sum over all its live programs there.

How this works: the simulator runs example scenarios (programs with
parameters, several origins, faults, relocation) with ``queued_bytes``
wrapped so that every call also computes the sum as it was written before
(every live program of the host, ``OFFERED`` there) and the two must agree.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from ramps.core import placing
from ramps.core.program import ProgramState
from ramps.sim.engine import simulate
from ramps.sim.scenario_file import load_scenario

EXAMPLES = Path(__file__).resolve().parent.parent / "examples"


def _all_live(origin: placing.PlacingOrigin, host: str) -> int:
    programs = origin.programs
    return sum(programs[pid].submit.payload_size for pid in origin.by_host.get(host, ())
               if programs[pid].state is ProgramState.OFFERED and programs[pid].host == host)


@pytest.mark.parametrize("policy", ["ramps", "paper"])
@pytest.mark.parametrize("scenario", ["warehouse.yaml", "relocation.yaml", "mis-measured.yaml",
                                      pytest.param("big-team.yaml", marks=pytest.mark.slow)])
def test_queued_bytes_is_the_sum_over_every_live_program(monkeypatch, scenario: str, policy: str) -> None:
    calls = {"n": 0, "nonzero": 0}
    fast = placing.queued_bytes

    def both(origin: placing.PlacingOrigin, host: str) -> int:
        got = fast(origin, host)
        assert got == _all_live(origin, host)
        calls["n"] += 1
        calls["nonzero"] += got > 0
        return got

    monkeypatch.setattr(placing, "queued_bytes", both)
    res = simulate(load_scenario(EXAMPLES / scenario), policy=policy)
    assert not res.lost and not res.duplicated
    assert calls["n"] > 0 and calls["nonzero"] > 0, calls


def test_delivered_programs_leave_the_offers_index() -> None:
    from ramps.sim.engine import simulate as run

    seen: list[int] = []
    fast = placing.queued_bytes

    def spy(origin: placing.PlacingOrigin, host: str) -> int:
        seen.append(sum(len(ids) for ids in origin.offered.values()))
        assert all(pid in origin.programs and origin.programs[pid].state not in (
            ProgramState.DONE, ProgramState.FAILED) for ids in origin.offered.values() for pid in ids)
        return fast(origin, host)

    mp = pytest.MonkeyPatch()
    mp.setattr(placing, "queued_bytes", spy)
    try:
        run(load_scenario(EXAMPLES / "warehouse.yaml"))
    finally:
        mp.undo()
    assert seen
