"""The calibrated work loop: what one work unit of CPU is.

How this works: ``spin(n)`` runs ``n`` iterations of a pure-Python integer
loop, a 32-bit linear congruential generator whose state is the result, so
the loop cannot be skipped and the same number of iterations gives the same
result on any machine. ``ITERATIONS_PER_UNIT`` iterations are one work unit,
about one CPU second on the calibration machine. The burn program
(``ramps.programs.burn``) does its work with it, and a node's speed probe
(``ramps.runtime.measure``) times it, so a speed of 1.0 means "as fast as the
calibration core" and a program of ``w`` units takes about ``w / speed`` CPU
seconds.
"""

from __future__ import annotations

# Measured on the development machine (AMD EPYC core, CPython 3.11.7, idle):
# the loop in spin ran 14.4-17.2 million iterations per CPU second, median
# ~16.0 M (15 runs of 2e7-3e7 iterations, time.process_time), so one unit
# ~= 1.0 CPU s there (expect +-10% run to run).
ITERATIONS_PER_UNIT = 16_000_000

#: the loop's state before the first iteration
SEED = 0x2545F491
#: the state's range: 0 to MASK (32 bits)
MASK = 0xFFFFFFFF

_A = 1_103_515_245
_C = 12_345


def spin(iterations: int, x: int = SEED) -> int:
    """The state after ``iterations`` more iterations from state ``x``."""
    a, c, mask = _A, _C, MASK  # locals: the loop cost does not depend on global lookups
    for _ in range(iterations):
        x = (x * a + c) & mask
    return x


__all__ = ["ITERATIONS_PER_UNIT", "MASK", "SEED", "spin"]
