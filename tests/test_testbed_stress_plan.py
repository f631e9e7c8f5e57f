"""The stressed campaign's plans (``ramps.lab.campaign.stress_plan``):
seeded, every fault of a robot undone before the run ends, an origin only
ever stalled briefly or crashed and recovered soon (pure, no testbed needed);
and the application's answer to an origin crash (``_wait_resubmitting``)."""

from __future__ import annotations

import random
from collections import Counter

import pytest

from ramps.lab.campaign import campaign_plan, stress_plan

NAMES = ["r1", "r2", "r3", "r4"]


def test_same_seed_same_plan_and_the_classic_plan_is_unchanged():
    assert stress_plan(random.Random(5), NAMES, 20.0) == stress_plan(random.Random(5), NAMES, 20.0)
    # --no-stress keeps the plans (and so the seeds) of campaigns measured before
    assert campaign_plan(random.Random(5), NAMES, 20.0) == campaign_plan(random.Random(5), NAMES, 20.0)


@pytest.mark.parametrize("origins", [1, 2])
def test_every_fault_is_undone_and_the_origins_only_stall_briefly_or_crash(origins):
    kinds: Counter = Counter()
    origin_kinds: Counter = Counter()
    for seed in range(300):
        plan = stress_plan(random.Random(seed), NAMES, 20.0, origins=origins)
        open_faults: dict[str, str] = {}
        for at, robot, kind in plan:
            base = kind.split(":")[0]
            kinds[base] += 1
            assert 0 <= at <= 20.0
            if base in ("recover", "unload"):
                assert robot in open_faults, (seed, plan)
                del open_faults[robot]
            else:
                assert robot not in open_faults, (seed, plan)  # one fault of a robot at a time
                open_faults[robot] = base
                if robot in NAMES[:origins]:
                    assert base in ("stall", "crash", "node_crash"), (seed, plan)
                    origin_kinds[base] += 1
        assert not open_faults, (seed, plan)
        for origin in NAMES[:origins]:
            faults = [(a, k) for a, r, k in plan if r == origin]
            if faults:
                (began, kind), (back, _) = faults
                assert back - began <= (2.0 if kind == "stall" else 4.0) + 0.01, (seed, plan)
    for k in ("crash", "cut", "freeze", "stall", "node_crash", "pressure"):
        assert kinds[k] > 10, kinds
    for k in ("stall", "crash", "node_crash"):  # origins crash too, robot or node alone
        assert origin_kinds[k] > 10 * origins, origin_kinds


class FakeTeam:
    """A Team whose node crashed once: the first submission of each program
    fails with ProgramLost, a later one completes."""

    robot = "r2"

    def __init__(self, lose: int) -> None:
        self.lose = lose
        self.submitted = 0

    def options(self, **_):
        return self

    def submit(self, program: str, units: float):
        from concurrent.futures import Future

        from ramps.errors import ProgramLost

        self.submitted += 1
        f: Future = Future()
        if self.submitted <= self.lose:
            f.set_exception(ProgramLost("r2, the origin of this program, left the team or died"))
        else:
            f.set_result({"units": units})
        return f


def test_the_application_submits_again_what_its_crashed_origin_lost():
    from ramps.lab.campaign import RESUBMITS, _wait_resubmitting

    team = FakeTeam(lose=3)
    futures = [(0.1 * i, team.submit("burn", 0.1 * i), 0) for i in range(3)]  # all three lost
    final, again = _wait_resubmitting(futures, [team], log=lambda _m: None, timeout=5.0)
    assert again == 3 and [f.result()["units"] for _, f, _ in final] == [0.0, 0.1, 0.2]
    # a program lost more than RESUBMITS times is given up (the run then counts it lost)
    team = FakeTeam(lose=100)
    final, again = _wait_resubmitting([(0.1, team.submit("burn", 0.1), 0)], [team], log=lambda _m: None)
    assert again == RESUBMITS and final[0][1].exception() is not None


def test_replacement_per_program_reads_the_kept_origin_trace(tmp_path):
    """``python -m ramps.lab.campaign``: from R5's crash (the origin
    wrote it off 0.1 s after) to each displaced program's next acceptance."""
    import json

    from ramps.lab.campaign import replacement_per_program

    d = tmp_path / "simultaneous_crash_R5-0"
    d.mkdir()
    lines = [(1.0, "accepted", "p1", "r5"), (1.0, "accepted", "p2", "r5"), (1.0, "accepted", "p3", "r2"),
             (10.1, "failed", "p1", "r5"), (10.2, "accepted", "p1", "r3"), (10.4, "accepted", "p2", "r4"),
             (10.5, "accepted", "p3", "r4")]  # p3 was not on r5: not displaced
    d.joinpath("r1.trace.jsonl").write_text("".join(
        json.dumps({"t": t, "robot": "r1", "what": w, "program_id": p, "other": o, "attempt": 1, "detail": ""}) + "\n"
        for t, w, p, o in lines))
    report = {"experiments": [{"mode": "simultaneous", "runs": [{"plan": "simultaneous crash: R5", "seed": 0,
                                                                "failures": [{"robot": "R5", "detection": 0.1}]}]}]}
    got = replacement_per_program(report, tmp_path)
    assert list(got) == ["simultaneous"] and [round(x, 3) for x in got["simultaneous"]] == [0.2, 0.4]
