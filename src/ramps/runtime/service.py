"""A node under a service manager: systemd's readiness, status and watchdog.

How this works: systemd starts ``ramps node`` with ``Type=notify`` and gives
it ``$NOTIFY_SOCKET``, a unix datagram socket; each notification is one
datagram of ``KEY=value`` lines (the sd_notify protocol, ``man sd_notify``).
The node says ``READY=1`` once it has joined its team (its Zenoh session is
open, its subscribers and liveliness token declared), ``STATUS=...`` lines
that ``systemctl status`` shows, and ``STOPPING=1`` when it starts to leave.

With ``WatchdogSec=`` systemd also sets ``$WATCHDOG_USEC`` (and
``$WATCHDOG_PID``, the process it means): unless it hears ``WATCHDOG=1`` that
often it kills the node (SIGABRT) and, with ``Restart=``, starts it again.
``Watchdog`` is fed by the node's driver loop itself
(``NodeRuntime.on_turn``, called after every round), at most every half
interval, so the node is restarted when its driver stalls (a deadlock, a
callback that never returns, a loop that no longer turns), not only when the
process dies. A small thread puts a no-op on the driver's queue when the loop
has not turned for an eighth of the interval, so an idle node, whose loop
sleeps until its next timer, still turns often enough; it never feeds the
watchdog itself.

Where no service manager listens (a container), ``$RAMPS_HEALTH_FILE`` names
a file that the same driver loop touches every ``HEALTH_PERIOD`` seconds; the
image's HEALTHCHECK calls the container unhealthy when it grows older than
``HEALTH_STALE`` (``python -m ramps.runtime.service FILE``).

Rules: standard library only (no systemd package); without ``$NOTIFY_SOCKET``
every call is a no-op, so the same code runs by hand, in a container and in
tests. A failed send is logged once and never raises: a node must not die
because its supervisor went away. The variables are taken out of the
environment once read, so workers and executables the node starts never
notify in its name.
"""

from __future__ import annotations

import logging
import os
import socket
import threading
import time
from typing import Any, Callable, Mapping

log = logging.getLogger("ramps.service")

ENV_VARS = ("NOTIFY_SOCKET", "WATCHDOG_USEC", "WATCHDOG_PID")
#: seconds between touches of $RAMPS_HEALTH_FILE, and the age at which it is stale
HEALTH_PERIOD = 5.0
HEALTH_STALE = 30.0


class Notifier:
    """Sends sd_notify datagrams to one socket (``$NOTIFY_SOCKET``: a path, or
    ``@name`` for the abstract namespace)."""

    def __init__(self, address: str) -> None:
        if not address or address[0] not in "/@":
            raise ValueError(f"NOTIFY_SOCKET must be a socket path or @abstract name, got {address!r}")
        self.address = "\0" + address[1:] if address[0] == "@" else address
        self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
        self._lock = threading.Lock()
        self._warned = False
        #: datagrams sent, and those that failed
        self.sent = 0
        self.failed = 0

    def notify(self, *lines: str) -> bool:
        """Send one datagram of these ``KEY=value`` lines. True if it went."""
        data = "\n".join(line.replace("\n", " ") for line in lines).encode()
        with self._lock:
            try:
                self._sock.sendto(data, self.address)
            except OSError as exc:
                self.failed += 1
                if not self._warned:
                    self._warned = True
                    log.warning("cannot notify the service manager at %s: %s", self.address.lstrip("\0"), exc)
                return False
            self.sent += 1
            return True

    def close(self) -> None:
        self._sock.close()


def watchdog_interval(environ: Mapping[str, str], pid: int | None = None) -> float | None:
    """Seconds within which the service manager wants ``WATCHDOG=1``, or None
    when it wants none (as ``sd_watchdog_enabled``: ``$WATCHDOG_USEC`` set and
    positive, and ``$WATCHDOG_PID``, when set, this process)."""
    raw = environ.get("WATCHDOG_USEC", "")
    try:
        usec = int(raw)
    except ValueError:
        return None
    if usec <= 0:
        return None
    want_pid = environ.get("WATCHDOG_PID", "")
    if want_pid:
        try:
            if int(want_pid) != (os.getpid() if pid is None else pid):
                return None
        except ValueError:
            return None
    return usec / 1e6


class Watchdog:
    """Feeds ``WATCHDOG=1`` through ``send`` at most every ``interval / 2``
    seconds, and only from ``turned()``: the driver calls it after each round
    of its loop. ``clock`` is monotonic seconds (a test passes a fake one)."""

    def __init__(self, send: Callable[[], Any], interval: float, *,
                 clock: Callable[[], float] = time.monotonic) -> None:
        if not interval > 0:
            raise ValueError(f"a watchdog interval must be > 0 seconds, got {interval}")
        self.interval = interval
        self.period = interval / 2
        self._send = send
        self._clock = clock
        self._fed_at: float | None = None
        self._turned_at = clock()
        self._stop = threading.Event()
        self._waker: threading.Thread | None = None
        #: WATCHDOG=1 sent
        self.fed = 0

    def turned(self) -> None:
        """The driver's loop turned: feed the watchdog if half an interval passed."""
        now = self._clock()
        self._turned_at = now
        if self._fed_at is None or now - self._fed_at >= self.period:
            self._fed_at = now
            self.fed += 1
            self._send()

    def quiet_for(self) -> float:
        """Seconds since the loop last turned."""
        return self._clock() - self._turned_at

    def start_waker(self, wake: Callable[[], None]) -> None:
        """A thread that calls ``wake()`` (put a no-op on the driver's queue)
        when the loop has not turned for an eighth of the interval: an idle
        driver sleeps until its next timer, possibly longer than the interval.
        So a healthy loop turns at least every quarter interval and is fed at
        least every three quarters. It never feeds the watchdog: a stalled
        driver leaves the no-ops queued."""
        def run() -> None:
            step = self.interval / 8
            while not self._stop.wait(step):
                if self.quiet_for() >= step:
                    try:
                        wake()
                    except Exception:  # pragma: no cover - never let the waker die loudly
                        log.debug("watchdog waker: wake failed", exc_info=True)

        self._waker = threading.Thread(target=run, name="ramps-watchdog-waker", daemon=True)
        self._waker.start()

    def stop(self) -> None:
        self._stop.set()
        if self._waker is not None and self._waker is not threading.current_thread():
            self._waker.join(1.0)


class Service:
    """What a node tells its service manager. ``Service.from_environ()`` is
    a no-op object when the node does not run under one."""

    def __init__(self, notifier: Notifier | None = None, watchdog_s: float | None = None,
                 health_file: str = "") -> None:
        self.notifier = notifier
        self.watchdog_s = watchdog_s if notifier is not None else None
        self.watchdog: Watchdog | None = None
        self.health_file = health_file
        self.health: Watchdog | None = None

    @classmethod
    def from_environ(cls, environ: dict[str, str] | os._Environ[str] | None = None, *,
                     unset: bool = True) -> "Service":
        """From ``$NOTIFY_SOCKET``, ``$WATCHDOG_USEC`` and ``$WATCHDOG_PID``
        (``environ``: default ``os.environ``), which are then taken out of it
        (``unset``) so that processes the node starts do not inherit them."""
        env = os.environ if environ is None else environ
        address = env.get("NOTIFY_SOCKET", "")
        interval = watchdog_interval(env)
        health = env.get("RAMPS_HEALTH_FILE", "")
        if unset:
            for var in ENV_VARS:
                env.pop(var, None)
        if not address:
            return cls(health_file=health)
        try:
            notifier = Notifier(address)
        except (ValueError, OSError) as exc:
            log.warning("not notifying the service manager: %s", exc)
            return cls(health_file=health)
        return cls(notifier, interval, health)

    @property
    def active(self) -> bool:
        return self.notifier is not None

    def _notify(self, *lines: str) -> None:
        if self.notifier is not None:
            self.notifier.notify(*lines)

    def attach(self, rt: Any) -> None:
        """Feed the watchdog and the health file from ``rt``'s driver loop (a
        started ``NodeRuntime``: ``on_turn`` is called after each round;
        ``call()`` wakes it). No-op without either."""
        dogs: list[Watchdog] = []
        if self.watchdog_s is not None and self.notifier is not None:
            notifier = self.notifier
            self.watchdog = Watchdog(lambda: notifier.notify("WATCHDOG=1"), self.watchdog_s)
            dogs.append(self.watchdog)
        if self.health_file:
            path = self.health_file
            self.health = Watchdog(lambda: touch(path), 2 * HEALTH_PERIOD)
            dogs.append(self.health)
        if not dogs:
            return
        def turned() -> None:
            for dog in dogs:
                dog.turned()

        rt.on_turn = dogs[0].turned if len(dogs) == 1 else turned
        min(dogs, key=lambda d: d.interval).start_waker(lambda: _wake(rt))

    def ready(self, status: str = "") -> None:
        """The node has joined its team."""
        self._notify("READY=1", *([f"STATUS={status}"] if status else []))

    def status(self, text: str) -> None:
        self._notify(f"STATUS={text}")

    def stopping(self, status: str = "") -> None:
        """The node is leaving its team (handing programs back)."""
        self._notify("STOPPING=1", *([f"STATUS={status}"] if status else []))

    def close(self) -> None:
        for dog in (self.watchdog, self.health):
            if dog is not None:
                dog.stop()
        if self.notifier is not None:
            self.notifier.close()
        if self.health_file:
            try:  # a node that left is not healthy
                os.unlink(self.health_file)
            except OSError:
                pass


def _noop() -> None:
    return None


def _wake(rt: Any) -> None:
    """Put a no-op on ``rt``'s driver queue, without waiting for it."""
    try:
        rt.call(_noop, timeout=0)
    except TimeoutError:
        pass  # queued; the driver takes it when it turns


_health_warned = False


def touch(path: str) -> None:
    """Set ``path``'s times to now (creating it); a failure is logged once."""
    global _health_warned
    try:
        with open(path, "a"):
            pass
        os.utime(path)
    except OSError as exc:
        if not _health_warned:
            _health_warned = True
            log.warning("cannot touch the health file %s: %s", path, exc.strerror or exc)


def healthy(path: str, stale: float = HEALTH_STALE) -> bool:
    """Whether the health file at ``path`` was touched within ``stale`` seconds."""
    try:
        return time.time() - os.stat(path).st_mtime < stale
    except OSError:
        return False


def main(argv: list[str] | None = None) -> int:
    """``python -m ramps.runtime.service [FILE]``: exit 0 if the node's health
    file (default ``$RAMPS_HEALTH_FILE``) is fresh, 1 if not (a HEALTHCHECK)."""
    import sys

    args = sys.argv[1:] if argv is None else argv
    path = args[0] if args else os.environ.get("RAMPS_HEALTH_FILE", "")
    if not path:
        print("no health file: give one, or set RAMPS_HEALTH_FILE", file=sys.stderr)
        return 2
    if healthy(path):
        return 0
    print(f"unhealthy: {path} is missing or older than {HEALTH_STALE:g} s (the node's driver loop "
          "stopped turning, or the node is not running)", file=sys.stderr)
    return 1


__all__ = ["HEALTH_PERIOD", "HEALTH_STALE", "Notifier", "Service", "Watchdog", "healthy", "main", "touch",
           "watchdog_interval"]

if __name__ == "__main__":
    raise SystemExit(main())
