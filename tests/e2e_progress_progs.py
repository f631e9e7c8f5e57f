"""A Python program that reports progress, for tests/test_command_e2e.py
(registered with ``--program e2e_progress_progs:stepper``)."""

from __future__ import annotations

import os
import time

import ramps


def stepper(steps: int = 5, dt: float = 0.3) -> dict:
    """Sleep ``steps`` times ``dt`` seconds, reporting progress after each."""
    for i in range(steps):
        time.sleep(dt)
        ramps.progress((i + 1) / steps, f"step {i + 1} of {steps}")
    return {"robot": os.environ.get("RAMPS_ROBOT"), "steps": steps}
