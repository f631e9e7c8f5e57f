"""Taking a testbed down when the process that made it ends.

How this works: ``DownOnExit(down)`` is the part of ``Testbed`` that
calls ``down`` at interpreter exit (``atexit``) and from SIGINT and
SIGTERM handlers installed over the previous ones. After ``down`` the
previous handler runs, or the process ends as the signal would have
ended it (KeyboardInterrupt, exit status 128 + the signal). Signal
handlers are installed from the main thread only (Python runs them
there); ``release`` puts the previous handlers back and drops the exit
hook (the testbed is down, or detached to outlive this process).
"""

from __future__ import annotations

import atexit
import signal
import threading
from collections.abc import Callable
from types import FrameType
from typing import Any

#: a signal's handler as ``signal.getsignal`` returns it
_Handler = Callable[[int, FrameType | None], Any] | int | signal.Handlers | None


class DownOnExit:
    """``down`` at interpreter exit and on SIGINT/SIGTERM, until ``release``."""

    def __init__(self, down: Callable[[], None]) -> None:
        self.down = down
        self._old: dict[int, _Handler] = {}
        self._atexit = False

    def install(self) -> None:
        if not self._atexit:
            atexit.register(self.down)
            self._atexit = True
        if threading.current_thread() is not threading.main_thread():
            return
        for sig in (signal.SIGINT, signal.SIGTERM):
            prev = signal.getsignal(sig)
            self._old[sig] = prev

            def handler(signum: int, frame: FrameType | None, prev: _Handler = prev) -> Any:
                self.down()
                if callable(prev):
                    return prev(signum, frame)
                if signum == signal.SIGINT:
                    raise KeyboardInterrupt
                raise SystemExit(128 + signum)

            signal.signal(sig, handler)

    def release(self) -> None:
        if self._old and threading.current_thread() is threading.main_thread():
            for sig, prev in self._old.items():
                try:
                    signal.signal(sig, prev if prev is not None else signal.SIG_DFL)
                except (ValueError, TypeError):
                    pass
            self._old = {}
        if self._atexit:
            atexit.unregister(self.down)
            self._atexit = False
