"""A Zenoh publisher's matching status (``Publisher.matching``), kept by a
matching listener rather than asked of Zenoh at each submission and each
outcome: on real sessions on loopback it follows a subscriber that comes,
goes and comes back, as Zenoh's own status does."""

from __future__ import annotations

import time
from typing import Callable

from ramps.runtime.settings import load_settings
from ramps.runtime.transport import ZenohTransport


def _session(connect: list[str], listen: list[str]) -> ZenohTransport:
    s = load_settings(flags={"team": "matching", "multicast": False, "connect": connect}, environ={},
                      default_robot=False)
    return ZenohTransport.open(s, listen=listen)


def _until(cond: Callable[[], bool], seconds: float = 5.0) -> bool:
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        if cond():
            return True
        time.sleep(0.005)
    return cond()


def test_matching_follows_a_subscriber_that_comes_goes_and_comes_back():
    a = _session([], ["tcp/127.0.0.1:0"])
    b = _session(a.locators(), [])
    try:
        assert _until(lambda: len(a.peers()) == 1)
        early = a.publisher("ramps/matching/client/c1", block=True)
        assert early.matching() is False  # nobody subscribes yet
        sub = b.subscribe("ramps/matching/client/c1", lambda data: None)
        assert _until(early.matching)
        late = a.publisher("ramps/matching/client/c1", block=True)  # declared while one matches: true at once
        assert late.matching() is True
        sub.undeclare()
        assert _until(lambda: not early.matching() and not late.matching())
        sub = b.subscribe("ramps/matching/client/c1", lambda data: None)
        assert _until(lambda: early.matching() and late.matching())
        for pub in (early, late):
            pub.undeclare()
        sub.undeclare()
    finally:
        b.close()
        a.close()
