"""T_comm measured per teammate: latency and bandwidth of each link.

How this works: every ``probe_period`` seconds a node that places programs
sends each teammate it could place on (at most ``placement_sample`` of them
in turn, ``Links.probes``) a small ``LinkProbe`` carrying its own clock;
the teammate answers at once with a ``LinkProbeReply`` echoing it, so
the round trip needs no shared clock. Every ``PADDED_EVERY``-th probe to a
robot carries ``PADDED_BYTES`` of padding (the first probe to a robot is a
plain one, the second padded): the extra time it takes over a plain one's
gives the bandwidth. A link not measured yet costs the configured
``NetworkEstimate``. A robot no application submits to measures each link
once (a plain probe and a padded one) and then only every
``IDLE_REFRESH`` probe periods: its links are ready when an application
starts submitting there (it probes every period from then on), without
every idle robot of a large team probing every teammate every period. In a
team of more than ``probe_rate`` x ``probe_period`` candidates, a robot
probes that many a period, the next ones in turn, and an idle one waits
longer still (``probe_budget``): probes per robot do not grow with the team.

The figures are the *least* round trips among the latest few: the latency
is half the least of the last ``PLAIN_WINDOW`` plain round trips, the
bandwidth the padding over the least of the last ``PADDED_WINDOW`` padded
round trips less that least plain one. Delays on top of a link's own time
only ever add (a node busy with other work, a robot whose CPU quota is spent
for the rest of its 100 ms period, a queue behind a big transfer), so the
least of a few samples is the link and an average of them is the noise:
averaged, full-speed links on the testbed read 0.15-2.2 MB/s from one late
probe in a few. A link whose padding adds less than ``MIN_TRANSFER`` is
faster than a probe can tell: it is given ``PADDED_BYTES / MIN_TRANSFER``
(164 MB/s), a figure that says "fast" without claiming more. A link that
slows down is seen once its faster samples leave the window (after
``PADDED_WINDOW`` padded probes). Pure state: ``now`` comes in, no I/O.

The estimate is of the path as a whole (both robots' radios, any switch, and
the receiving node's reaction time), which is what a program's parameters
and result also cross.
"""

from __future__ import annotations

import math
from collections import deque

import msgspec

from ramps.core.config import RampsConfig
from ramps.core.cost import NetworkEstimate
from ramps.core.events import Send
from ramps.core.messages import LinkProbe, LinkProbeReply

#: probe periods between probes of a link already measured, from a robot no application submits to
IDLE_REFRESH = 6
#: padding of a bandwidth probe, and how often a link gets one
PADDED_BYTES = 16 * 1024
PADDED_EVERY = 3
#: the padding itself, one immutable object every padded probe carries
_PADDING = bytes(PADDED_BYTES)
#: how many of the latest plain and padded round trips the least is taken of
PLAIN_WINDOW = 5
PADDED_WINDOW = 3
#: padding that adds less than this many seconds: a link faster than a probe can tell
MIN_TRANSFER = 1e-4
#: sizes of (parameters, result) whose T_comm per robot ``Links.comm_times`` keeps
COMM_SIZES = 8


def probe_budget(config: RampsConfig, teammates: int, submits: bool) -> tuple[int, float]:
    """(``most``, ``refresh``) for ``Links.probes`` of one probe period on
    a robot of ``teammates`` candidates besides it: at most
    ``placement_sample`` and ``probe_rate`` x ``probe_period`` probes; a robot
    no application ``submits`` to probes a link again only after
    ``IDLE_REFRESH`` times the period, or the time the team's links take at
    ``probe_rate`` when longer, so it sends at most a ``IDLE_REFRESH``-th of
    that rate whatever the team's size."""
    most = config.placement_sample
    if config.probe_rate > 0:
        budget = max(1, round(config.probe_rate * config.probe_period))
        most = budget if most <= 0 else min(most, budget)
    if submits:
        return most, 0.0
    period = config.probe_period
    if config.probe_rate > 0:
        period = max(period, teammates / config.probe_rate)
    return most, IDLE_REFRESH * period


def in_turn(items: list[str], turn: int, most: int) -> tuple[list[str], int]:
    """``most`` of ``items`` from position ``turn`` on (wrapping round), and
    where the next ones start: a list too long to take whole, taken a part
    at a time so that every item comes round."""
    start = turn % len(items)
    return (items[start:] + items[:start])[:most], start + most


class LinkEstimate(msgspec.Struct, kw_only=True):
    latency: float | None = None
    bandwidth: float | None = None
    probes: int = 0
    replies: int = 0


class _Link:
    __slots__ = ("probes", "replies", "plain", "padded", "size", "waiting", "latency", "bandwidth", "sent", "estimate")

    def __init__(self) -> None:
        self.probes = self.replies = self.size = 0
        #: when the latest probe went
        self.sent = -math.inf
        #: probes sent and not answered yet: send time -> padding (the latest few)
        self.waiting: dict[float, int] = {}
        self.plain: deque[float] = deque(maxlen=PLAIN_WINDOW)
        self.padded: deque[float] = deque(maxlen=PADDED_WINDOW)
        #: the figures, updated with each reply (read at every placement)
        self.latency: float | None = None
        self.bandwidth: float | None = None
        #: ``Links.estimate`` of these figures, made at its first reading after each update
        self.estimate: NetworkEstimate | None = None

    def update(self) -> None:
        self.estimate = None
        self.latency = min(self.plain) / 2 if self.plain else None
        # bandwidth is what the padding adds over a plain round trip
        self.bandwidth = (self.size / max(MIN_TRANSFER, min(self.padded) - min(self.plain))
                          if self.plain and self.padded else None)


class Links:
    def __init__(self, default: NetworkEstimate) -> None:
        self.default = default
        self._links: dict[str, _Link] = {}
        #: where the next round of probes starts in a list of too many candidates (``probes``)
        self._turn = 0
        #: T_comm by (parameter bytes, result bytes), then by robot (``comm_times``)
        self._comm: dict[tuple[int, int], dict[str, float]] = {}

    def __call__(self, robot: str) -> NetworkEstimate:
        """``estimate``: a ``Links`` is what placement's ``links`` asks (``ramps.core.policy``)."""
        return self.estimate(robot)

    def comm_times(self, payload: int, result: int) -> dict[str, float]:
        """T_comm (``comm_time``) of ``payload`` and ``result`` bytes by robot, as far as its
        caller filled it in from ``estimate``: each robot's figure stands until its link's
        figures change (a probe's reply), so placement prices a link once, not at every
        scan. At most ``COMM_SIZES`` sizes are kept."""
        key = (payload, result)
        out = self._comm.get(key)
        if out is None:
            if len(self._comm) >= COMM_SIZES:
                self._comm.clear()
            out = self._comm[key] = {}
        return out

    def probes(self, candidates: list[str], me: str, now: float, most: int, refresh: float = 0.0) -> list[Send]:
        """The probes of one ``probe_period``: one to each candidate but
        ``me``; where there are more than ``most`` (``placement_sample``, 0:
        no limit), to ``most`` of them, the next ones in turn, so a probe's
        traffic stays bounded in a large team and every link is still
        measured every few periods. ``refresh`` > 0: not to a link measured
        (latency and bandwidth) and probed within the last ``refresh`` seconds."""
        if refresh > 0.0:
            others = [robot for robot in candidates if robot != me and not self._fresh(robot, now, refresh)]
        else:  # nothing is fresh: a node that submits probes every period
            others = [robot for robot in candidates if robot != me]
        if 0 < most < len(others):
            others, self._turn = in_turn(others, self._turn, most)
        return [Send(to=robot, msg=self.probe(robot, now)) for robot in others]

    def _fresh(self, robot: str, now: float, refresh: float) -> bool:
        link = self._links.get(robot)
        return (refresh > 0.0 and link is not None and link.bandwidth is not None and link.latency is not None
                and now - link.sent < refresh)

    def probe(self, robot: str, now: float) -> LinkProbe:
        link = self._links.get(robot)
        if link is None:
            link = self._links[robot] = _Link()
        padded = link.probes % PADDED_EVERY == 1  # the first probe measures latency
        link.probes += 1
        link.sent = now
        link.waiting[now] = PADDED_BYTES if padded else 0
        while len(link.waiting) > 2 * PADDED_EVERY:  # unanswered for long: lost
            del link.waiting[next(iter(link.waiting))]
        return LinkProbe(sent_at=now, padding=_PADDING if padded else b"")

    def on_reply(self, robot: str, msg: LinkProbeReply, now: float) -> None:
        link = self._links.get(robot)
        if link is None or msg.sent_at not in link.waiting:
            return  # a reply to nothing we sent (or answered already)
        size = link.waiting.pop(msg.sent_at)
        rtt = now - msg.sent_at
        if not 0.0 <= rtt < 60.0:
            return
        link.replies += 1
        if size == 0:
            link.plain.append(rtt)
        else:
            link.padded.append(rtt)
            link.size = size
        link.update()
        for times in self._comm.values():
            times.pop(robot, None)

    def estimate(self, robot: str) -> NetworkEstimate:
        """What a message to ``robot`` costs, measured where it was."""
        link = self._links.get(robot)
        if link is None or link.latency is None:
            return self.default
        if link.estimate is None:
            link.estimate = NetworkEstimate(
                latency=link.latency, bandwidth=self.default.bandwidth if link.bandwidth is None else link.bandwidth)
        return link.estimate

    def measured(self) -> dict[str, LinkEstimate]:
        return {r: LinkEstimate(latency=link.latency, bandwidth=link.bandwidth, probes=link.probes,
                                replies=link.replies)
                for r, link in self._links.items() if link.replies}
