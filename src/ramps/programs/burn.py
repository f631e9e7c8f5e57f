"""A calibrated CPU burn, and trivial programs for dispatch benchmarks.

How this works: ``burn`` runs a fixed number of iterations of the calibrated
work loop (``ramps.runtime.spin``: a 32-bit linear congruential generator
folded into a checksum). The amount of work is fixed by the arguments, never
by a clock: on an idle core ``burn(seconds=s)`` takes about ``s`` CPU seconds
on the calibration machine, and on a loaded or slower machine it simply
takes longer, which is what a load-sharing experiment needs.

Rules:
    * 1 work unit = ``ITERATIONS_PER_UNIT`` iterations ~= 1 CPU second on the
      calibration machine; ``seconds`` is shorthand for the same number of
      units (``units`` wins when both are given).
    * The checksum depends on every iteration, so the loop cannot be skipped,
      and it is the same for the same number of iterations on any machine.
    * Results are JSON-friendly dicts; bad arguments raise ``ValueError``.
    * ``checkpoint_every`` (units, 0: never) makes the burn report its
      progress and save its place (``ramps.checkpoint``) after every that
      many units; moved or restarted, it resumes from the last saved place
      (``ramps.resume()``), and the checksum is the same as an uninterrupted
      burn's, so a test can tell a resumed burn from a wrong one.
"""

from __future__ import annotations

import math
from typing import Any

from ramps.runtime.spin import ITERATIONS_PER_UNIT, MASK, SEED, spin

MAX_UNITS = 1_000_000.0  # ~11.5 CPU days: anything above is surely a mistake


def burn(seconds: float = 1.0, *, units: float | None = None, checkpoint_every: float = 0.0) -> dict[str, Any]:
    """Spin the CPU for ``units`` work units (default: ``seconds``); returns units, iterations, checksum
    (and ``resumed_at``, the iterations a resumed burn found done, when ``checkpoint_every`` > 0)."""
    amount = seconds if units is None else units
    name = "seconds" if units is None else "units"
    for label, value in ((name, amount), ("checkpoint_every", checkpoint_every)):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError(f"{label} must be a number, got {value!r}")
        if not math.isfinite(value) or value < 0:
            raise ValueError(f"{label} must be a finite number >= 0, got {value!r}")
        if value > MAX_UNITS:
            raise ValueError(f"{label} must be at most {MAX_UNITS:g}, got {value!r}")
    iterations = round(amount * ITERATIONS_PER_UNIT)
    if not checkpoint_every:
        return {"units": float(amount), "iterations": iterations, "checksum": spin(iterations)}
    import ramps

    done, x = 0, SEED
    saved = ramps.resume()
    if isinstance(saved, dict) and saved.get("iterations") == iterations:  # our own place, not another burn's
        done, x = int(saved["done"]), int(saved["x"])
        if not (0 <= done <= iterations and 0 <= x <= MASK):
            raise ValueError(f"a checkpoint outside this burn: {saved!r}")
    resumed_at = done
    step = max(1, round(checkpoint_every * ITERATIONS_PER_UNIT))
    while done < iterations:
        n = min(step, iterations - done)
        x = spin(n, x)
        done += n
        if done < iterations:
            ramps.progress(done / iterations)
            ramps.checkpoint({"iterations": iterations, "done": done, "x": x})
    return {"units": float(amount), "iterations": iterations, "checksum": x, "resumed_at": resumed_at}


def burn_accel(units: float = 1.0, accel_units: float = 0.05) -> dict[str, Any]:
    """A program that can use an accelerator (``cuda``): ``units`` of CPU
    burn where it runs on a CPU, ``accel_units`` of an emulated accelerator's
    work where its robot gave it one (the testbed's stand-in for a GPU:
    ``Grant.emulate``). Returns where it ran and what it did."""
    import ramps

    grant = ramps.accelerator()
    if grant is None:
        return {"on": "cpu", **burn(units=units)}
    if not grant.emulated:
        raise ValueError(f"burn_accel only emulates an accelerator; {grant.device} is a real one "
                         f"(see examples/accelerated.py for a program that uses it)")
    if isinstance(accel_units, bool) or not isinstance(accel_units, (int, float)) or \
            not (math.isfinite(accel_units) and 0 <= accel_units <= MAX_UNITS):
        raise ValueError(f"accel_units must be a finite number in 0..{MAX_UNITS:g}, got {accel_units!r}")
    wall = grant.emulate(accel_units)
    return {"on": grant.device, "units": float(accel_units), "wall": round(wall, 4)}


def noop(**kwargs: Any) -> dict[str, Any]:
    """Do nothing and return ``{}``: the cost of dispatch alone."""
    return {}


def echo(**kwargs: Any) -> dict[str, Any]:
    """Return the arguments unchanged (round-trip check)."""
    return dict(kwargs)
