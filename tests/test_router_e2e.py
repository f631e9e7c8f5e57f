"""End to end through a router: ``ramps router`` and three ``ramps node --mode client`` on loopback.

The nodes never link to each other: each links only to the router (client
mode, no listen endpoint), so every program that runs on another robot than
its origin went through the router. Then the router is SIGKILLed and
started again on the same port: the nodes and the application relink by
themselves, the program in flight during the outage is delivered once, and
the team is whole again. Last, Ctrl-C (SIGINT) stops the router with exit
status 0. About 15 s; no namespaces, no cgroups (docs/sites-and-routers.md).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
import uuid
from collections import Counter

import pytest
from runtime_team import _STARTED, RUN_ENV, RUN_ID, TESTS_DIR, assert_no_leftovers, wait_for

from ramps.runtime.client import Team
from ramps.runtime.settings import load_settings
from ramps.testing.local import free_port

pytestmark = pytest.mark.slow

ROBOTS = ("r1", "r2", "r3")


def _env(robot: str | None = None) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("RAMPS_") or k == "RAMPS_STATE_DIR"}
    env["PYTHONPATH"] = os.pathsep.join([str(TESTS_DIR)] + [p for p in [os.environ.get("PYTHONPATH")] if p])
    env[RUN_ENV] = RUN_ID
    if robot:
        env["RAMPS_ROBOT"] = robot
    return env


class Site:
    """A router and client-mode nodes on loopback, all killed on exit."""

    def __init__(self, tmp) -> None:
        self.tmp = tmp
        self.team = f"e2e-rt-{uuid.uuid4().hex[:10]}"
        self.port = free_port()
        self.router_ep = f"tcp/127.0.0.1:{self.port}"
        self.procs: list[subprocess.Popen] = []
        self.router: subprocess.Popen | None = None
        self.clients: list[Team] = []

    def _popen(self, argv: list[str], name: str, robot: str | None = None) -> subprocess.Popen:
        log = open(self.tmp / f"{name}.log", "ab")
        try:
            p = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=log, stderr=subprocess.STDOUT,
                                 env=_env(robot), start_new_session=True)
        finally:
            log.close()
        self.procs.append(p)
        _STARTED.append(p)
        return p

    def start_router(self) -> subprocess.Popen:
        self.router = self._popen([sys.executable, "-m", "ramps.cli", "router", "--listen", self.router_ep,
                                   "--no-multicast", "--lease-ms", "1000"], "router")
        wait_for(lambda: "listening on" in self.log("router") or self.router.poll() is not None, 20,
                 "the router to start")
        assert self.router.poll() is None, self.log("router")
        return self.router

    def start_node(self, robot: str) -> None:
        self._popen([sys.executable, "-m", "ramps.cli", "node", "--robot", robot, "--team", self.team,
                     "--mode", "client", "--connect", self.router_ep, "--no-multicast", "--cores", "1",
                     "--speed", "1", "--lease-ms", "1000", "--program", "e2eprogs:sleepy", "--trace", str(self.tmp / f"{robot}.trace.jsonl")], robot, robot)

    def client(self, robot: str = "r1", timeout: float = 20.0) -> Team:
        s = load_settings(flags={"team": self.team, "mode": "client", "connect": [self.router_ep],
                                 "multicast": False, "lease_ms": 1000}, environ={}, default_robot=False)
        t = Team(s, robot=robot, timeout=timeout)
        self.clients.append(t)
        return t

    def log(self, name: str) -> str:
        try:
            return (self.tmp / f"{name}.log").read_text(errors="replace")
        except OSError:
            return ""

    def whole(self, team: Team) -> bool:
        """Every robot alive, publishing, and seeing both others."""
        st = {r.robot: r for r in team.status().robots}
        return all(n in st and st[n].alive and st[n].report_age is not None and st[n].report_age < 3
                   and st[n].sees == len(ROBOTS) - 1 for n in ROBOTS)

    def close(self) -> None:
        for t in self.clients:
            t.close()
        for p in self.procs:
            if p.poll() is None:
                try:
                    os.killpg(p.pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
            p.wait(10)


def test_client_mode_nodes_share_programs_through_a_router_that_restarts(tmp_path):
    site = Site(tmp_path)
    try:
        site.start_router()
        for r in ROBOTS:
            site.start_node(r)
        team = site.client("r1")
        wait_for(lambda: site.whole(team), 30, "three client-mode nodes to see each other through the router\n"
                 + "\n".join(site.log(r)[-1500:] for r in ROBOTS))
        # round robin over the robots r1 sees: r2 and r3 are reached only through the router
        # (where ramps's own policy places is not what this test is about)
        rr = team.options(policy="round_robin")
        first = [f.result(timeout=60)["robot"] for f in [rr.submit("sleepy", seconds=0.5) for _ in range(6)]]
        assert set(first) == set(ROBOTS), f"programs did not reach every robot: {Counter(first)}"

        # the router dies with a program in flight, and comes back on the same port
        inflight = team.options(policy="round_robin").submit("sleepy", seconds=2.0, tag="during")
        time.sleep(0.3)
        os.killpg(site.router.pid, signal.SIGKILL)
        site.router.wait(10)
        time.sleep(1.5)  # past the 1 s lease: the robots have written each other off
        site.start_router()
        assert inflight.result(timeout=60)["tag"] == "during"  # delivered once (a future resolves once)
        wait_for(lambda: site.whole(team), 30, "the team to heal after the router restarted\n"
                 + "\n".join(site.log(r)[-1500:] for r in ROBOTS))
        after = [f.result(timeout=60)["robot"] for f in [rr.submit("sleepy", seconds=0.5) for _ in range(6)]]
        assert set(after) == set(ROBOTS), f"after the restart programs did not reach every robot: {Counter(after)}"

        # Ctrl-C stops the router cleanly
        site.router.send_signal(signal.SIGINT)
        assert site.router.wait(15) == 0, site.log("router")
        assert "ramps router: stopped" in site.log("router")
    finally:
        site.close()
    assert_no_leftovers()
