"""A secured team's router (``ramps router --secure``), in-process on loopback.

The router holds a team certificate and the team's access control, as a
node does: two client-mode sessions of the team exchange data through it on
the team's keys, nothing outside ``ramps/<team>/**`` passes, and a stranger
whose CA is another (same team name) is refused before Zenoh opens. About a
second; no processes.
"""

from __future__ import annotations

import time

import pytest

from ramps.errors import NotAdmitted
from ramps.runtime.router import Router
from ramps.runtime.security import admission, create_ca, issue, settings_credentials
from ramps.runtime.settings import load_settings
from ramps.runtime.transport import ZenohTransport
from ramps.testing.local import free_port

pytestmark = pytest.mark.slow  # Zenoh sessions

TEAM = "sec-rt"


def _client(endpoint: str, creds_dir) -> ZenohTransport:
    s = load_settings(flags={"team": TEAM, "mode": "client", "connect": [endpoint], "multicast": False,
                             "secure": True, "credentials": str(creds_dir)}, environ={}, default_robot=False)
    creds = settings_credentials(s)
    return ZenohTransport.open(s, credentials=creds, fail_fast=admission(s.connect, creds, team=TEAM))


def _heard(got: list, timeout: float = 5.0) -> bool:
    deadline = time.monotonic() + timeout
    while not got and time.monotonic() < deadline:
        time.sleep(0.02)
    return bool(got)


def test_a_secured_router_carries_the_team_and_nothing_else(tmp_path):
    create_ca(tmp_path / "ca", TEAM)
    create_ca(tmp_path / "rogue", TEAM)  # same team name, another CA
    endpoint = f"tls/127.0.0.1:{free_port()}"
    rs = load_settings(flags={"team": TEAM, "secure": True, "credentials": str(issue(tmp_path / "ca", "router-a")),
                              "listen": [endpoint], "multicast": False}, environ={}, default_robot=False)
    with Router.open(rs) as router:
        assert router.credentials.robot == "router-a" and router.listening == [endpoint]
        a = _client(endpoint, issue(tmp_path / "ca", "n1"))
        b = _client(endpoint, issue(tmp_path / "ca", "n2"))
        try:
            team_msgs: list[bytes] = []
            other_msgs: list[bytes] = []
            b.subscribe(f"ramps/{TEAM}/test", team_msgs.append)
            b.subscribe("elsewhere/test", other_msgs.append)
            deadline = time.monotonic() + 5.0
            while not team_msgs and time.monotonic() < deadline:  # until the subscription has reached a
                a.put(f"ramps/{TEAM}/test", b"hello")
                a.put("elsewhere/test", b"leak")
                time.sleep(0.05)
            assert _heard(team_msgs) and team_msgs[0] == b"hello"
            time.sleep(0.3)
            assert other_msgs == []  # the router's access control (and the clients') let nothing else through
        finally:
            a.close()
            b.close()
        with pytest.raises(NotAdmitted, match="another CA"):
            _client(endpoint, issue(tmp_path / "rogue", "x"))
