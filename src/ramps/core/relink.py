"""After this robot's own stall: which teammates' links are not back yet.

How this works: a node whose driver did not run for a while (SIGSTOP, a
robot starved of CPU, a long pause) wakes to find that its teammates' leases
on it ran out meanwhile: the transport closes their links and rebuilds them,
which takes up to a few seconds on a loaded robot. Until a teammate's link is
back, nothing it sends arrives (its heartbeats, its acceptance of an offer)
and nothing sent to it does (an offer). The driver says so with one event,
``Stalled(seconds=...)``, when it wakes; from then for ``timeout`` seconds
every teammate is *relinking* until it is heard again:

- a teammate's silence is not counted while it relinks: the origin's
  heartbeat and connect timeouts on it wait for the link, and once it is
  back they count from that moment (``ramps.core.silence``);
- no new offer goes to a teammate that relinks while another is back
  (placement excludes it); while every teammate relinks, the policy chooses
  among all of them as usual, rather than pile everything on this robot;
- a teammate is back when the transport says so (``PeerAlive``), or when a
  message from it arrives at least ``settle`` seconds after the wake (the
  messages it sent before its link closed are read right after the wake and
  prove nothing); one never heard within ``timeout`` counts as silent
  again, from the time it was last heard, as if there had been no stall.

Rules: no clock (``now`` comes in), no I/O. A stall shorter than the
transport's lease never closes links; the driver reports only those that
may have (``ramps.runtime.node``: three quarters of the lease or more, as
keep-alives go out every quarter), so a busy robot's short stalls do not
keep its teammates out of placement.
"""

from __future__ import annotations

from collections.abc import Iterable

import msgspec

#: seconds after a stall during which a teammate not heard again is relinking
RELINK_TIMEOUT = 3.0
#: seconds after the wake before a message proves its sender's link is back
RELINK_SETTLE = 0.25


class Stalled(msgspec.Struct, frozen=True, kw_only=True):
    """The driver did not run for ``seconds`` (driver -> core, at the wake).
    Every stall is told (the origin counts a host's silence from the wake,
    ``Origin.on_stalled``); ``links``: long enough that teammates' links may
    have closed, so they relink as above."""

    seconds: float
    links: bool = True


class Relink:
    """The teammates whose links may still be down after this robot's stall."""

    def __init__(self, me: str, *, timeout: float = RELINK_TIMEOUT, settle: float = RELINK_SETTLE) -> None:
        if timeout < 0 or settle < 0:
            raise ValueError(f"relink timeout and settle must be >= 0, got {timeout} and {settle}")
        self.me = me
        self.timeout = timeout
        self.settle = settle
        self.woke = -float("inf")
        self.until = -float("inf")
        #: teammates heard again since the last stall
        self.back: set[str] = set()
        #: stalls reported, and teammates that came back within the timeout
        self.stalls = 0
        self.relinked = 0

    def stalled(self, now: float) -> None:
        self.stalls += 1
        self.woke = now
        self.until = now + self.timeout
        self.back = set()

    def active(self, now: float) -> bool:
        return now < self.until

    def waiting(self, host: str | None, now: float) -> bool:
        """Whether ``host``'s link may still be down: its silence does not count."""
        return host is not None and host != self.me and now < self.until and host not in self.back

    def heard(self, host: str, now: float, *, certain: bool = False) -> bool:
        """Something came from ``host`` (``certain``: the transport says its
        link is back). True when this brings it back from relinking."""
        if not self.waiting(host, now) or (not certain and now < self.woke + self.settle):
            return False
        self.back.add(host)
        self.relinked += 1
        return True

    def excluded(self, robots: Iterable[str], now: float) -> frozenset[str]:
        """The robots among ``robots`` not to offer anything to now: none
        when that would be every teammate (this robot would then run
        everything itself, however loaded, until one is heard again)."""
        if now >= self.until:
            return frozenset()
        teammates = [r for r in robots if r != self.me]
        out = frozenset(r for r in teammates if self.waiting(r, now))
        return frozenset() if len(out) == len(teammates) else out
