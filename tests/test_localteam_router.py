"""A ``LocalTeam`` joined by a Zenoh router (``router=True``): every node a
Zenoh client of the router, as a large team runs. Real processes."""

from __future__ import annotations

import time

import psutil
import pytest

from ramps.testing import LocalTeam

pytestmark = pytest.mark.slow


def test_nodes_that_are_clients_of_a_router_form_one_team_and_share_work(tmp_path):
    with LocalTeam(4, tmp_path, cores=1, speed=1.0, router=True) as t:
        assert t.endpoints() == [t.router_endpoint]
        # no node listens: each links to the router only
        ports = {c.laddr.port for n in t.nodes.values()
                 for c in psutil.Process(n.pid).net_connections(kind="tcp") if c.status == psutil.CONN_LISTEN}
        assert ports == set(), ports
        team = t.client("r1")
        deadline = time.monotonic() + 20  # until its client has heard every robot's report
        while (sees := {r.robot: r.sees for r in team.status().robots}) != {f"r{i}": 3 for i in range(1, 5)} \
                and time.monotonic() < deadline:
            time.sleep(0.2)
        assert sees == {f"r{i}": 3 for i in range(1, 5)}
        # in turn over the robots: the robots share this host's load, which the
        # default policy would read as every robot as busy as the others
        futures = [team.options(policy="round_robin").submit("burn", units=0.05) for _ in range(4)]
        assert all(f.result(timeout=120)["iterations"] > 0 for f in futures)
        assert len({f.host for f in futures}) >= 3, [f.host for f in futures]  # offered through the router
