"""Programs that kill their own worker, for the poison-pill tests
(tests/test_poison_pill.py): each is a module-level function, so a worker
pool (tests/ on its PYTHONPATH) or a node can run it."""

from __future__ import annotations

import os
import signal
import sys


def exits(code: int = 3, say: str = "") -> None:
    """Write ``say`` to stderr, then end the worker with exit code ``code``."""
    if say:
        print(say, file=sys.stderr, flush=True)
    os._exit(code)


def segfaults() -> None:
    """Crash the worker in C (SIGSEGV): a read of address 0."""
    import ctypes

    ctypes.string_at(0)


def kills_itself() -> None:
    os.kill(os.getpid(), signal.SIGKILL)


def quits(code: int = 4) -> None:
    """``sys.exit`` from a program: its own error, its worker lives on."""
    sys.exit(code)


def fine(x: int = 1) -> int:
    return x
