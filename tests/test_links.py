"""T_comm measured per teammate (``ramps.core.links``): the least round trips
of the latest few are the link; late replies are noise and do not move it."""

from __future__ import annotations

import random

import pytest

from ramps.core.cost import NetworkEstimate
from ramps.core.links import MIN_TRANSFER, PADDED_BYTES, PADDED_WINDOW, Links
from ramps.core.messages import LinkProbeReply

DEFAULT = NetworkEstimate(latency=0.005, bandwidth=2.5e6)


def exchange(links: Links, robot: str, now: float, latency: float, bandwidth: float, delay: float = 0.0) -> float:
    """One probe and its reply over a link of that latency and bandwidth, ``delay`` late."""
    probe = links.probe(robot, now)
    rtt = 2 * latency + len(probe.padding) / bandwidth + delay
    links.on_reply(robot, LinkProbeReply(sent_at=probe.sent_at, size=len(probe.padding)), now + rtt)
    return now + 5.0


def test_a_link_not_measured_costs_the_default_and_one_plain_reply_gives_its_latency() -> None:
    links = Links(DEFAULT)
    assert links.estimate("r2") == DEFAULT and links.measured() == {}
    exchange(links, "r2", 0.0, latency=0.002, bandwidth=1e6)
    assert links.estimate("r2") == NetworkEstimate(latency=pytest.approx(0.002), bandwidth=DEFAULT.bandwidth)


def test_late_replies_do_not_drag_a_fast_link_down() -> None:
    # robots of a fraction of a host core: replies wait out a spent CPU quota
    # (up to 110 ms late, as measured on the testbed); here two padded replies
    # in three and every other plain one are late
    rng = random.Random(1)
    links, now = Links(DEFAULT), 0.0
    for i in range(60):
        padded = i % 3 == 1
        late = (i // 3) % 3 != 0 if padded else i % 2 == 0
        now = exchange(links, "r2", now, latency=0.0005, bandwidth=1e9,
                       delay=rng.uniform(0.005, 0.11) if late else 0.0)
        if i >= 3 * PADDED_WINDOW:  # a window of padded replies with one on time
            assert links.estimate("r2").bandwidth == PADDED_BYTES / MIN_TRANSFER  # "fast", no slow link's figure
    assert links.estimate("r2").latency == pytest.approx(0.0005)


def test_a_slow_link_reads_its_rate_and_a_link_that_slows_down_is_seen_within_the_window() -> None:
    links, now = Links(DEFAULT), 0.0
    for _ in range(12):
        now = exchange(links, "r3", now, latency=0.001, bandwidth=1e5, delay=0.0)
    assert links.estimate("r3").bandwidth == pytest.approx(1e5, rel=0.01)
    for _ in range(12):
        now = exchange(links, "r2", now, latency=0.001, bandwidth=1e9)
    assert links.estimate("r2").bandwidth > 100 * links.estimate("r3").bandwidth
    # r2's link is throttled to 1 MB/s: read once its fast padded samples have left the window
    probes = 0
    while links.estimate("r2").bandwidth > 2e6:
        now = exchange(links, "r2", now, latency=0.001, bandwidth=1e6)
        probes += 1
        assert probes <= 3 * PADDED_WINDOW + 3, "the slowdown was not seen"
    assert links.estimate("r2").bandwidth == pytest.approx(1e6, rel=0.01)


def test_replies_to_probes_never_sent_or_answered_twice_change_nothing() -> None:
    links, now = Links(DEFAULT), 0.0
    for _ in range(4):
        now = exchange(links, "r2", now, latency=0.002, bandwidth=1e6)
    before = links.estimate("r2")
    # a forged reply claiming a probe sent a moment ago, and padding it never had
    links.on_reply("r2", LinkProbeReply(sent_at=now - 1e-6, size=PADDED_BYTES), now)
    links.on_reply("r9", LinkProbeReply(sent_at=0.0, size=0), now)
    probe = links.probe("r2", now)
    links.on_reply("r2", LinkProbeReply(sent_at=probe.sent_at, size=len(probe.padding)), now + 0.004)
    replies = links.measured()["r2"].replies
    links.on_reply("r2", LinkProbeReply(sent_at=probe.sent_at, size=len(probe.padding)), now + 0.0001)
    assert links.measured()["r2"].replies == replies and "r9" not in links.measured()
    assert links.estimate("r2").latency == pytest.approx(before.latency)


def test_an_idle_robot_measures_each_link_once_then_rarely_and_a_submitter_every_period() -> None:
    """A robot no application submits to probes a teammate until it has its
    latency and bandwidth, then every IDLE_REFRESH periods; from its first
    Submit, every period again."""
    from corehelpers import report

    from ramps.core.config import RampsConfig
    from ramps.core.events import Received, Submit
    from ramps.core.links import IDLE_REFRESH
    from ramps.core.messages import LinkProbe
    from ramps.core.node import Node

    period = 5.0
    node = Node("r1", cores=2, speed=1.0, config=RampsConfig(probe_period=period), rng=random.Random(0))
    probes: list[float] = []
    t = 0.0
    while t <= 100.0:
        node.handle(Received(sender="r2", msg=report("r2", seq=int(t) + 1)), t)
        for a in node.tick(t):
            if isinstance(getattr(a, "msg", None), LinkProbe):
                probes.append(t)  # answered at once over a fast link
                node.handle(Received(sender="r2", msg=LinkProbeReply(sent_at=a.msg.sent_at,
                                                                     size=len(a.msg.padding))), t + 0.001)
        t += period
    assert probes[:2] == [0.0, 5.0]  # a plain probe, then a padded one: measured
    assert [b - a for a, b in zip(probes[1:], probes[2:])] == [IDLE_REFRESH * period] * (len(probes) - 2)
    node.handle(Submit(program_id="p1", program="noop", work=0.001), t)
    later = []
    for _ in range(4):
        node.handle(Received(sender="r2", msg=report("r2", seq=int(t) + 1)), t)
        later += [t for a in node.tick(t) if isinstance(getattr(a, "msg", None), LinkProbe)]
        t += period
    assert later == [t - 4 * period + k * period for k in range(4)]  # every period once an application submits


def test_probes_per_robot_do_not_grow_with_the_team() -> None:
    """In a view of 120 teammates, a submitter probes at most ``probe_rate`` x
    ``probe_period`` of them a period (the next ones in turn: every link
    within a few periods), and an idle robot, once its links are measured,
    about a sixth of that; in a team of 40 nothing changes."""
    from corehelpers import report

    from ramps.core.config import RampsConfig
    from ramps.core.events import Received, Submit
    from ramps.core.links import IDLE_REFRESH, probe_budget
    from ramps.core.messages import LinkProbe
    from ramps.core.node import Node

    assert probe_budget(RampsConfig(probe_rate=0), 120, False) == (64, IDLE_REFRESH * 5.0)  # no limit
    cfg = RampsConfig(probe_rate=8.0)
    assert probe_budget(cfg, 40, True) == (40, 0.0) and probe_budget(cfg, 40, False) == (40, IDLE_REFRESH * 5.0)
    assert probe_budget(cfg, 120, True) == (40, 0.0)
    assert probe_budget(cfg, 120, False) == (40, IDLE_REFRESH * 15.0)
    assert probe_budget(RampsConfig(probe_rate=0), 120, True) == (64, 0.0)

    def run(submits: bool, seconds: float) -> tuple[int, set[str]]:
        node = Node("r0", cores=1, speed=1.0, config=cfg, rng=random.Random(0))
        if submits:
            node.handle(Submit(program_id="p1", program="noop", work=0.001), 0.0)
        sent, to = 0, set()
        t = 0.0
        while t < seconds:
            for i in range(1, 121):
                node.handle(Received(sender=f"r{i}", msg=report(f"r{i}", seq=int(t) + 1)), t)
            for a in node.tick(t):
                if isinstance(getattr(a, "msg", None), LinkProbe):
                    sent += 1
                    to.add(a.to)
                    node.handle(Received(sender=a.to, msg=LinkProbeReply(sent_at=a.msg.sent_at,
                                                                         size=len(a.msg.padding))), t + 0.001)
            t += cfg.probe_period
        return sent, to

    sent, to = run(True, 100.0)
    assert sent <= 40 * 20 and len(to) == 120  # 20 periods; every teammate in turn
    idle, _ = run(False, 300.0)
    assert idle / 300.0 <= 8.0 / IDLE_REFRESH * 1.5  # past the first measurements: a sixth of a submitter's
