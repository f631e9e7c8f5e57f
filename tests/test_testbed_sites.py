"""Two sites behind two routers on the testbed (ramps.testbed.sites), the smallest case.

r1 on site A's bridge and r2 on site B's reach each other only through
router A -> router B (separate subnets, no forwarding): one team, a program
of r1's runs on r2; router A killed, the sites are apart; router A started
again, the team is whole. Needs root and cpu cgroups (skipped otherwise).
The full experiment, with the slow link and figures, is ``ramps testbed
experiment sites``.
"""

from __future__ import annotations

import time

import pytest

from test_testbed import REASON, others_leftovers, wait_until

pytestmark = [pytest.mark.slow, pytest.mark.skipif(REASON is not None, reason=REASON or "")]


def test_two_sites_form_one_team_through_routers_and_heal_after_a_router_crash():
    from ramps.testbed import net
    from ramps.testbed.bed import watch_team
    from ramps.testbed.sites import ROUTER, Sites

    before = others_leftovers()
    with Sites(1, speed=1.0, cores=1, lease_ms=1000) as s:
        tbs = [s.a.tb, s.b.tb]
        assert s.robots == ["r1", "r2"]
        assert s.a.ip("r1").rsplit(".", 1)[0] != s.b.ip("r2").rsplit(".", 1)[0]  # two subnets
        with s.a.client("r1", timeout=30.0) as team:
            rr = team.options(policy="round_robin")
            futs = [rr.submit("crunch", data=b"x" * 1000, units=0.01) for _ in range(2)]
            assert [f.result(timeout=60) for f in futs] == [{"bytes": 1000}] * 2
            assert {f.host for f in futs} == {"r1", "r2"}  # one crossed both routers
        with watch_team(s.b) as obs:
            s.a.crash(ROUTER)
            assert wait_until(lambda: obs.ready() == {"r2"}, 20), obs.ready()  # site B alone
        s.a.start_router()
        t = time.monotonic()
        s.wait_whole(30.0)
        assert time.monotonic() - t < 30
    left = set(net.namespaces())
    assert not [n for n in left if any(f"-{tb}-" in n for tb in tbs)], left
    assert others_leftovers() == before
