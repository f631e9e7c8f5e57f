"""The stressed campaign's plans (``ramps.testbed.experiments.stress_plan``):
seeded, every fault of a robot undone before the run ends, the origin only
ever stalled briefly (pure, no testbed needed)."""

from __future__ import annotations

import random
from collections import Counter

import pytest

from ramps.testbed.experiments import campaign_plan, stress_plan

NAMES = ["r1", "r2", "r3", "r4"]


def test_same_seed_same_plan_and_the_classic_plan_is_unchanged():
    assert stress_plan(random.Random(5), NAMES, 20.0) == stress_plan(random.Random(5), NAMES, 20.0)
    # --no-stress keeps the plans (and so the seeds) of campaigns measured before
    assert campaign_plan(random.Random(5), NAMES, 20.0) == campaign_plan(random.Random(5), NAMES, 20.0)


@pytest.mark.parametrize("origins", [1, 2])
def test_every_fault_is_undone_and_the_origins_only_stall_briefly(origins):
    kinds: Counter = Counter()
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
                    assert base == "stall", (seed, plan)
        assert not open_faults, (seed, plan)
        for origin in NAMES[:origins]:
            stalls = [a for a, r, k in plan if r == origin]
            if stalls:
                assert stalls[1] - stalls[0] <= 2.0 + 0.01
    for k in ("crash", "cut", "freeze", "stall", "node_crash", "pressure"):
        assert kinds[k] > 10, kinds
