"""A calibrated CPU burn, and trivial programs for dispatch benchmarks.

How this works: ``burn`` runs a fixed number of iterations of a pure-Python
integer loop (a 32-bit linear congruential generator folded into a
checksum). The amount of work is fixed by the arguments, never by a clock: on
an idle core ``burn(seconds=s)`` takes about ``s`` CPU seconds on the
calibration machine, and on a loaded or slower machine it simply takes
longer, which is what a load-sharing experiment needs.

Rules:
    * 1 work unit = ``ITERATIONS_PER_UNIT`` iterations ~= 1 CPU second on the
      calibration machine; ``seconds`` is shorthand for the same number of
      units (``units`` wins when both are given).
    * The checksum depends on every iteration, so the loop cannot be skipped,
      and it is the same for the same number of iterations on any machine.
    * Results are JSON-friendly dicts; bad arguments raise ``ValueError``.
"""

from __future__ import annotations

import math
from typing import Any

# Measured on the development machine (AMD EPYC core, CPython 3.11.7, idle):
# the loop in _spin ran 14.4-17.2 million iterations per CPU second, median
# ~16.0 M (15 runs of 2e7-3e7 iterations, time.process_time), so one unit
# ~= 1.0 CPU s there (expect +-10% run to run).
ITERATIONS_PER_UNIT = 16_000_000

MAX_UNITS = 1_000_000.0  # ~11.5 CPU days: anything above is surely a mistake

_A = 1_103_515_245
_C = 12_345
_MASK = 0xFFFFFFFF


def _spin(iterations: int) -> int:
    a, c, mask = _A, _C, _MASK  # locals: the loop cost does not depend on global lookups
    x = 0x2545F491
    for _ in range(iterations):
        x = (x * a + c) & mask
    return x


def burn(seconds: float = 1.0, *, units: float | None = None) -> dict[str, Any]:
    """Spin the CPU for ``units`` work units (default: ``seconds``); returns units, iterations, checksum."""
    amount = seconds if units is None else units
    name = "seconds" if units is None else "units"
    if isinstance(amount, bool) or not isinstance(amount, (int, float)):
        raise ValueError(f"{name} must be a number, got {amount!r}")
    if not math.isfinite(amount) or amount < 0:
        raise ValueError(f"{name} must be a finite number >= 0, got {amount!r}")
    if amount > MAX_UNITS:
        raise ValueError(f"{name} must be at most {MAX_UNITS:g}, got {amount!r}")
    iterations = round(amount * ITERATIONS_PER_UNIT)
    return {"units": float(amount), "iterations": iterations, "checksum": _spin(iterations)}


def noop(**kwargs: Any) -> dict[str, Any]:
    """Do nothing and return ``{}``: the cost of dispatch alone."""
    return {}


def echo(**kwargs: Any) -> dict[str, Any]:
    """Return the arguments unchanged (round-trip check)."""
    return dict(kwargs)
