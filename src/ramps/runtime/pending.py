"""A client's pending programs: their futures, their submissions until the node has them, their timeouts.

How this works: ``Pending`` is the table a ``Team`` keeps of the programs
it submitted and that have not finished: request id -> ``ProgramFuture``.
A submission is sent once and kept (``sending``) until the node
acknowledges it (``acked``: an update or the outcome): a submission
published while the node's link lapsed (a node stalled, starved of CPU) is
lost, so the timer thread (``run``, "ramps-client-timers") sends it again
every ``SUBMIT_RESEND`` seconds while the node is reachable (the node runs
one program per request), and, once the node's link is back after a lapse
(``ask_again``), asks again about every pending program. A call with a
timeout (``add``) is failed with ``TimeoutError`` and withdrawn when it is
due. The thread sleeps until the next of these is due; a new timer or
resend wakes it only if it is due sooner (a burst of submissions wakes it
none).

Rules: one lock, the Team's, guards the table (the Team's transport
callbacks run on other threads); every method but ``run`` is called with it
held, and ``run`` lets go of it whenever it sends or fails a future. The
Team's publisher is reached through ``send``, ``reachable`` and
``withdraw``, so the thread may start before the node is found.
"""

from __future__ import annotations

import heapq
import threading
from collections.abc import Callable

from ramps.runtime.futures import ProgramFuture
from ramps.runtime.transport import Clock

#: seconds between two looks for the node while submissions wait for it
HELD_RETRY = 0.05
#: a submission the node has not acknowledged (no update, no outcome) is sent
#: again after this many seconds; the node runs one program per request
SUBMIT_RESEND = 1.0


class Pending:
    """The programs one client submitted that have not finished (see the module docstring)."""

    def __init__(self, lock: threading.Lock, clock: Clock, *, send: Callable[[bytes], None],
                 reachable: Callable[[], bool], withdraw: Callable[[int], None]) -> None:
        self._lock = lock
        self.clock = clock
        self._send = send
        self._reachable = reachable
        self._withdraw = withdraw
        #: request id -> its program's future
        self.futures: dict[int, ProgramFuture] = {}
        #: per-call timeouts: (when, request id)
        self._timers: list[tuple[float, int]] = []
        self._cv = threading.Condition(lock)
        #: when the timer thread wakes next, monotonic (-inf while it runs): a new
        #: timer or resend wakes it only if due sooner (``_wake``)
        self._wake_at = -float("inf")
        #: submissions the node has not acknowledged yet: request id -> (bytes, when to send again)
        self._unacked: dict[int, tuple[bytes, float]] = {}
        #: every pending submission as sent, to ask again once the node's link is back after a lapse
        self._sent: dict[int, bytes] = {}
        self.closed = False

    def add(self, rid: int, fut: ProgramFuture, timeout: float | None) -> None:
        """A new program, failed after ``timeout`` seconds (None: never)."""
        self.futures[rid] = fut
        if timeout is not None:
            when = self.clock.monotonic() + timeout
            heapq.heappush(self._timers, (when, rid))
            self._wake(when)

    def sending(self, rid: int, data: bytes, reachable: bool) -> None:
        """``data`` submits program ``rid``: kept until the node has it, and
        sent again in ``SUBMIT_RESEND`` seconds (at once if the node is not
        ``reachable`` now: the thread sends it when it is)."""
        again = self.clock.monotonic() + (SUBMIT_RESEND if reachable else 0.0)
        self._unacked[rid] = (data, again)
        self._sent[rid] = data
        self._wake(again)

    def acked(self, rid: int) -> ProgramFuture | None:
        """The node has program ``rid`` (an update came): no need to send it again."""
        self._unacked.pop(rid, None)
        return self.futures.get(rid)

    def forget(self, rid: int) -> ProgramFuture | None:
        """Program ``rid`` is over (or was never sent): its future, taken out."""
        self._unacked.pop(rid, None)
        self._sent.pop(rid, None)
        return self.futures.pop(rid, None)

    def take_all(self) -> list[ProgramFuture]:
        """Every pending future, taken out (its node is gone, or the Team closes)."""
        futs = list(self.futures.values())
        self.futures.clear()
        return futs

    def ask_again(self) -> None:
        """The node's link is back after a lapse: an outcome it sent meanwhile
        went nowhere, so every pending program is asked about again, now."""
        now = self.clock.monotonic()
        for rid in self.futures:
            if rid in self._sent:
                self._unacked[rid] = (self._sent[rid], now)
        self._cv.notify()

    def stop(self) -> None:
        """The Team closes: the timer thread ends."""
        self.closed = True
        self._cv.notify_all()

    def run(self) -> None:
        """The timer thread: resend what is due, time out what is due, sleep until the next."""
        with self._lock:
            while not self.closed:
                retry = self._resend_due() if self._unacked else None
                if not self._timers:
                    self._wait(retry or 0.5)
                    continue
                when, rid = self._timers[0]
                delay = when - self.clock.monotonic()
                if delay > 0:
                    self._wait(min(delay, retry) if retry else delay)
                    continue
                heapq.heappop(self._timers)
                fut = self.futures.get(rid)
                if fut is not None and not fut.done():
                    self._lock.release()
                    try:
                        try:
                            fut.set_exception(TimeoutError(f"{fut.program} did not finish in time; withdrawn"))
                        except Exception:
                            pass
                        self._withdraw(rid)
                    except Exception:
                        pass
                    finally:
                        self._lock.acquire()

    def _resend_due(self) -> float | None:
        """Send again the submissions that are due, if the node is reachable
        (withdrawn ones are forgotten). Returns the seconds until the next is due."""
        now = self.clock.monotonic()
        due = [(rid, data) for rid, (data, at) in self._unacked.items() if at <= now]
        if due and self._reachable():
            for rid, data in due:
                if rid not in self.futures:
                    self._unacked.pop(rid, None)
                    continue
                self._unacked[rid] = (data, now + SUBMIT_RESEND)
                self._lock.release()
                try:
                    self._send(data)
                except Exception:
                    pass
                finally:
                    self._lock.acquire()
        if not self._unacked:
            return None
        return max(HELD_RETRY, min(at for _, at in self._unacked.values()) - self.clock.monotonic())

    def _wake(self, due: float) -> None:
        """Wake the timer thread if something is now due before it would wake."""
        if due < self._wake_at:
            self._wake_at = -float("inf")
            self._cv.notify()

    def _wait(self, seconds: float) -> None:
        """The timer thread waits ``seconds``, or until woken."""
        self._wake_at = self.clock.monotonic() + seconds
        self._cv.wait(seconds)
        self._wake_at = -float("inf")
