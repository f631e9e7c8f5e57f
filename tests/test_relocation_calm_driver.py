"""Calm on a struggling robot (issue 23), the stall and the driver's side:
heartbeats a stalled origin could not hear in time never write off a
healthy host, and a driver with a long queue still sends what it owes its
team (load report, its programs' heartbeats) before it drains the rest, while
the origin's timeouts wait for the queue. Real core ``Node``s in a
``FakeTeam``, and the real driver's round with a fake clock."""

from __future__ import annotations

import os
import random

import pytest

import ramps.runtime.node as rn
from corehelpers import busy_origin_team, report, submit
from ramps.core.events import Received
from ramps.core.messages import Heartbeat
from ramps.core.node import Node
from ramps.core.program import ProgramState
from ramps.core.relink import Stalled
from ramps.runtime.settings import load_settings
from ramps.testing.memory import FakeClock


def test_heartbeats_a_short_stall_of_the_origin_held_back_do_not_write_off_its_host():
    team = busy_origin_team()
    submit(team, "p", work=60.0)
    team.deliver()
    host = team.program("p").host
    team.advance(4.5)  # heard at 4.5 last
    # the origin's driver stalled (1.5 s, out of its clock; too short for its
    # links to close) and wakes at 4.5: the heartbeats its host sent meanwhile
    # come in 2.3 s later, behind the stall
    team.handle("o", Stalled(seconds=1.5, links=False))
    team.advance(6.8, hold=lambda s, to, m: isinstance(m, Heartbeat) and s == host)
    team.release()
    team.advance(12.0)
    ap = team.program("p")
    assert ap.state is ProgramState.RUNNING and ap.host == host and ap.attempt == 1
    assert not team.notes("failed") and not team.nodes["o"].view.blacklisted()
    assert not team.notes("relinking"), "a short stall closes no links: teammates stay placeable"


def test_a_host_silent_for_a_whole_timeout_after_the_wake_is_still_written_off():
    team = busy_origin_team()
    submit(team, "p", work=60.0)
    team.deliver()
    host = team.program("p").host
    team.advance(4.5)
    team.handle("o", Stalled(seconds=1.5, links=False))
    team.cut.add(host)  # it is really gone
    team.advance(7.9)
    assert team.program("p").host == host, "silence counts from the wake plus the stall's length"
    team.advance(8.5)
    assert [n.robot for n in team.notes("failed")] == [host]


@pytest.fixture
def driver():
    fake = FakeClock()
    rt = rn.NodeRuntime(load_settings(flags={"robot": "r1", "team": "t"}, environ={}), clock=fake)
    rt.node = Node("r1", cores=2, speed=1.0, rng=random.Random(0))
    rt.node.handle(Received(sender="r2", msg=report("r2")), fake.t)
    rt.awake.last_read = fake.t
    rt._next_pub = fake.t
    return rt, fake


def test_a_long_queue_does_not_hold_back_the_load_report_nor_wait_for_the_origins_timeouts(driver, monkeypatch):
    rt, fake = driver
    handled, published, ticks = [], [], []
    item_cost = 0.002  # seconds per queued message on a saturated robot

    def handle(item, now):
        fake.t += item_cost
        handled.append(item)
        return []

    monkeypatch.setattr(rt.inbound, "handle", handle)
    monkeypatch.setattr(rt.outbound, "publish", lambda now: published.append(now))
    monkeypatch.setattr(rt.outbound, "apply", lambda actions: None)
    real_tick = rt.node.tick
    monkeypatch.setattr(rt.node, "tick", lambda now, origin=True: ticks.append(origin) or real_tick(now, origin=origin))
    monkeypatch.setattr(rt.node, "next_deadline", lambda: fake.t - 1.0)  # the origin's timers are due
    for i in range(1000):  # 2 s of work queued
        rt._q.put(("call", i))
    assert rt.step()
    assert len(handled) == pytest.approx(rn.ROUND_SECONDS / item_cost, abs=2), "one round's share of the queue"
    assert published and ticks == [False], "the load report and heartbeats went out; the origin's timeouts wait"
    while not rt._q.empty():
        rt.step()
    assert len(handled) == 1000 and ticks[-1] is True and rt.rounds_cut >= 10


def test_the_node_gives_itself_its_niceness_and_its_workers_still_get_theirs(tmp_path):
    """In a child process (niceness sticks to a process): as root, the node
    runs at node_nice and a worker it starts adds what brings it to
    worker_nice; without the right, it says so in one line and stays."""
    import subprocess
    import sys

    code = ("import os, ramps.runtime.node as rn\n"
            "ok = rn.prioritize(-5)\n"
            "print(ok, os.getpriority(os.PRIO_PROCESS, 0), rn.worker_increment(10))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    ok, nice, inc = out.stdout.split()
    if os.geteuid() == 0:
        assert (ok, int(nice), int(inc)) == ("True", -5, 15)
    else:
        assert (ok, int(inc)) == ("False", 10 - int(nice)) and "cannot give itself niceness" in out.stderr
