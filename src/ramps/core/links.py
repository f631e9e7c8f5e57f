"""T_comm measured per teammate: latency and bandwidth of each link.

How this works: every ``probe_period`` seconds a node that places programs
sends each teammate it could place on a small ``LinkProbe`` carrying its own
clock; the teammate answers at once with a ``LinkProbeReply`` echoing it, so
the round trip needs no shared clock. Every ``PADDED_EVERY``-th probe to a
robot carries ``PADDED_BYTES`` of padding: the extra
time it takes over the link's latency gives the bandwidth (so the first
probe to a robot is a plain one, the second padded). Each link keeps an
exponentially weighted average of both; a link not measured yet costs the
configured ``NetworkEstimate``. Pure state: ``now`` comes in, no I/O.

The estimate is of the path as a whole (both robots' radios, any switch, and
the receiving node's reaction time), which is what a program's parameters
and result also cross.
"""

from __future__ import annotations

import msgspec

from ramps.core.cost import NetworkEstimate
from ramps.core.messages import LinkProbe, LinkProbeReply

#: padding of a bandwidth probe, and how often a link gets one
PADDED_BYTES = 16 * 1024
PADDED_EVERY = 6
#: weight of a new sample in the running averages
ALPHA = 0.3
#: a sample below this many seconds of transfer says nothing about bandwidth
MIN_TRANSFER = 1e-4


class LinkEstimate(msgspec.Struct, kw_only=True):
    latency: float | None = None
    bandwidth: float | None = None
    probes: int = 0
    replies: int = 0


class Links:
    def __init__(self, default: NetworkEstimate) -> None:
        self.default = default
        self._links: dict[str, LinkEstimate] = {}

    def probe(self, robot: str, now: float) -> LinkProbe:
        link = self._links.setdefault(robot, LinkEstimate())
        padded = link.probes % PADDED_EVERY == 1  # the first probe measures latency
        link.probes += 1
        return LinkProbe(sent_at=now, padding=b"\0" * PADDED_BYTES if padded else b"")

    def on_reply(self, robot: str, msg: LinkProbeReply, now: float) -> None:
        link = self._links.get(robot)
        rtt = now - msg.sent_at
        if link is None or not 0.0 <= rtt < 60.0:
            return  # a reply to nothing we sent, or from the future
        link.replies += 1
        if msg.size == 0:
            link.latency = rtt / 2 if link.latency is None else (1 - ALPHA) * link.latency + ALPHA * rtt / 2
            return
        if link.latency is None:
            return  # bandwidth is what the padding adds over a latency we know
        transfer = rtt - 2 * link.latency
        if transfer >= MIN_TRANSFER:
            bw = msg.size / transfer
            link.bandwidth = bw if link.bandwidth is None else (1 - ALPHA) * link.bandwidth + ALPHA * bw

    def estimate(self, robot: str) -> NetworkEstimate:
        """What a message to ``robot`` costs, measured where it was."""
        link = self._links.get(robot)
        if link is None or (link.latency is None and link.bandwidth is None):
            return self.default
        return NetworkEstimate(latency=self.default.latency if link.latency is None else link.latency,
                               bandwidth=self.default.bandwidth if link.bandwidth is None else link.bandwidth)

    def measured(self) -> dict[str, LinkEstimate]:
        return {r: msgspec.structs.replace(l) for r, l in self._links.items() if l.replies}
