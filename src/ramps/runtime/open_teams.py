"""The Teams an application left open, closed when the interpreter exits.

How this works: Zenoh runs subscriber callbacks on non-daemon threads, so
an open session would keep the process alive after the script's last line.
Every ``Team`` is tracked (``track``) in a weak set from the moment its
session opens until it closes (``forget``); the first one hooks
``close_open_teams`` where ``concurrent.futures`` hooks its own clean-up,
which runs before Python waits for non-daemon threads (plain ``atexit``
would be too late), falling back on ``atexit`` where that hook is missing.
"""

from __future__ import annotations

import atexit
import threading
import weakref
from typing import Protocol


class Closable(Protocol):
    def close(self) -> None: ...


#: Teams still open, closed at interpreter exit if the application did not
_OPEN: weakref.WeakSet[Closable] = weakref.WeakSet()
_OPEN_LOCK = threading.Lock()
_EXIT_HOOKED = False


def close_open_teams() -> None:
    """Close every Team the application left open."""
    with _OPEN_LOCK:
        teams = list(_OPEN)
    for team in teams:
        try:
            team.close()
        except Exception:
            pass


def track(team: Closable) -> None:
    """``team`` is open: close it at exit unless it is closed first."""
    global _EXIT_HOOKED
    with _OPEN_LOCK:
        _OPEN.add(team)
        if not _EXIT_HOOKED:
            try:  # the hook concurrent.futures uses: before non-daemon threads are joined
                threading._register_atexit(close_open_teams)  # type: ignore[attr-defined]
            except (AttributeError, RuntimeError):
                atexit.register(close_open_teams)
            _EXIT_HOOKED = True


def forget(team: Closable) -> None:
    """``team`` is closed."""
    with _OPEN_LOCK:
        _OPEN.discard(team)
