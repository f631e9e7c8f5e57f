"""A program whose declared work depends on its arguments, for
tests/test_learning.py (tests/ is on the path)."""

from __future__ import annotations

import ramps


@ramps.program(work=lambda picks, **_: 0.5 * picks)
def sized(picks: int = 4, seed: int = 0) -> int:
    return picks + seed
