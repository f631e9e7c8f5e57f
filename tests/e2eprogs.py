"""Small ramps programs for the end-to-end tests (tests/test_runtime_e2e.py).

Every ``ramps node`` of a ``runtime_team.LocalTeam`` registers them with
``--program e2eprogs:<name>`` (tests/ is on the nodes' PYTHONPATH) and is
started with ``RAMPS_ROBOT`` set to its robot name; a program's worker
process inherits the node's environment, so a result says which robot ran
it. Results are plain msgpack-encodable values.
"""

from __future__ import annotations

import os
import time

import ramps


def _me() -> str | None:
    return os.environ.get("RAMPS_ROBOT")


def where(x: int = 0) -> dict:
    """Which robot (and which worker process) ran this call."""
    return {"robot": _me(), "pid": os.getpid(), "x": x}


def spin(seconds: float = 0.5) -> str:
    """Burn ``seconds`` of this process's CPU time; return the robot name."""
    end = time.process_time() + seconds
    n = 0
    while time.process_time() < end:
        n += 1
    return _me()


def sleepy(seconds: float = 1.0, tag: str = "") -> dict:
    """Sleep (no CPU) and say where and in which worker process it ran.

    Before sleeping, the worker records its pid in ``$RAMPS_E2E_MARKS/<tag>``
    (when both are set) so a test can find the worker running this program."""
    marks = os.environ.get("RAMPS_E2E_MARKS")
    if tag and marks:
        path = os.path.join(marks, tag)
        with open(path + ".tmp", "w") as f:
            f.write(f"{_me()} {os.getpid()}\n")
        os.replace(path + ".tmp", path)
    time.sleep(seconds)
    return {"robot": _me(), "pid": os.getpid(), "tag": tag}


def fail() -> None:
    raise ValueError("no route to the dock")


def big(n: int) -> bytes:
    """A result of ``n`` bytes."""
    return b"x" * n


def stamp(seconds: float = 1.0) -> list:
    """Sleep; return [started, ended] (CLOCK_MONOTONIC, one clock for every process)."""
    started = time.monotonic()
    time.sleep(seconds)
    return [started, time.monotonic()]


def resumable(steps: int = 10, dt: float = 0.25) -> dict:
    """Count to ``steps``, one step per ``dt`` seconds, saving the count
    after each step (``ramps.checkpoint``); resumed, it goes on from the
    saved count. Returns the step it started from and the robot."""
    import ramps

    state = ramps.resume() or {"i": 0}
    first = state["i"]
    for i in range(first, steps):
        time.sleep(dt)
        ramps.progress((i + 1) / steps)
        ramps.checkpoint({"i": i + 1})
    return {"robot": _me(), "first": first}


@ramps.program(accelerator="cuda", cpu_fallback=False, accelerator_work=0.1)
def needs_cuda(x: int = 1) -> dict:
    """A program that runs only where a robot offers a ``cuda`` accelerator."""
    grant = ramps.accelerator()
    return {"robot": _me(), "device": None if grant is None else grant.device, "x": x}
