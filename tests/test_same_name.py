"""Two nodes under one robot name (machines cloned from one disk image share
their host name, the default name): one of them leaves with a clear error,
the same one whichever hears the other first; a restarted node's previous
process, whose last report may still be on its way, is not a clash. The
real driver and core over the in-memory transport."""

from __future__ import annotations

import time
from typing import Any, Callable

import pytest

from ramps.runtime.node import NodeRuntime
from ramps.runtime.settings import load_settings
from ramps.testing.memory import MemoryBus, MemoryPool, MemoryTeam, StillSampler


def clone(team: MemoryTeam, robot: str, incarnation: int) -> NodeRuntime:
    """A second node named ``robot``, on its own transport."""
    s = load_settings(flags={"robot": robot, "team": team.team, "cores": 2, "speed": 1.0}, environ={})
    rt = NodeRuntime(s, transport=team.bus.transport(f"{robot}-clone"), clock=team.clock, worker_pool=MemoryPool,
                     load_sampler=StillSampler, incarnation=incarnation)
    rt.start(threaded=False)
    team.nodes[f"{robot}-clone"] = rt
    return rt


@pytest.mark.parametrize("clone_incarnation, leaves", [(99, "clone"), (1, "first")])
def test_two_nodes_with_one_name_one_leaves_and_says_why(clone_incarnation, leaves, caplog):
    team = MemoryTeam({"r1": (2, 1.0), "r2": (2, 1.0)})  # r2's incarnation is 2
    try:
        team.run(3.0)
        first, other = team.nodes["r2"], clone(team, "r2", clone_incarnation)
        team.run(5.0)
        gone, stays = (other, first) if leaves == "clone" else (first, other)
        assert gone.wait(0) and "robot name 'r2' is used by two nodes of team 'mem'" in gone.name_taken
        assert "give each robot its own name" in gone.name_taken
        assert not stays.wait(0) and stays.name_taken == ""
        assert any("leaves the team" in r.getMessage() for r in caplog.records)
    finally:
        team.close()


def test_the_last_report_of_a_previous_process_is_not_a_clash():
    team = MemoryTeam({"r1": (2, 1.0), "r2": (2, 1.0)})
    try:
        team.run(3.0)
        old = team.nodes["r2"]
        report = old._last_report
        team.kill("r2")
        new = team.add("r2", seed=5)  # the supervisor's restart: a new incarnation
        from ramps.core.messages import encode
        from ramps.runtime import keys

        team.bus.transport("stray").put(keys.load(team.team, "r2"), encode("r2", report))  # still on its way
        team.run(5.0)
        assert new._same_name_seen == {report.incarnation: report.seq}  # heard, and not taken for a clash
        assert not new.wait(0) and new.name_taken == ""
    finally:
        team.close()


def test_a_client_keeps_its_robot_when_a_refused_clone_of_it_leaves():
    """The clone's liveliness token has the running node's key: when it goes,
    Zenoh tells nobody (a key goes when its last token does), so a client of
    the running node still sees it alive, and its program is not lost."""
    from ramps.runtime.client import Team

    team = MemoryTeam({"r1": (2, 1.0), "r2": (2, 1.0)})
    s = load_settings(flags={"team": team.team}, environ={}, default_robot=False)
    client = Team(s, robot="r2", timeout=1.0, transport=team.bus.transport("app"), clock=team.clock,
                  origin_grace=0.0)  # a robot seen gone fails its programs at once
    try:
        team.run(3.0)
        fut = client.submit("echo", x=1)
        team.run(1.0, complete=False)
        other = clone(team, "r2", 99)
        team.run(5.0, complete=False)
        assert other.wait(0) and other.name_taken, "the clone left"
        assert {r.robot: r.alive for r in client.status().robots} == {"r1": True, "r2": True}
        team.run(1.0)
        assert fut.result(timeout=5) == {"x": 1}
    finally:
        client.close()
        team.close()


KEY = "same-name/alive/r2"
#: what a liveliness subscriber hears after each step of ``one_key_two_tokens``
ONE_KEY_TWO_TOKENS = [[(KEY, True)], [(KEY, True)], [(KEY, True)], [(KEY, True), (KEY, False)]]


def one_key_two_tokens(a: Any, b: Any, watcher: Any, wait: Callable[..., None]) -> list[list[tuple[str, bool]]]:
    """Two transports declare one key (two nodes under one name), then the
    second closes and the first undeclares it: what ``watcher`` has heard
    after each step."""
    heard: list[tuple[str, bool]] = []
    watcher.subscribe_liveliness("same-name/alive/*", lambda key, alive: heard.append((key, alive)), history=True)
    steps = []
    token = a.declare_token(KEY)
    wait(lambda: heard)
    steps.append(list(heard))
    b.declare_token(KEY)
    wait()
    steps.append(list(heard))
    b.close()
    wait()
    steps.append(list(heard))
    token.undeclare()
    wait(lambda: len(heard) > 1)
    steps.append(list(heard))
    return steps


def test_the_memory_bus_tells_a_key_as_zenoh_does_not_each_token():
    bus = MemoryBus()
    a, b, watcher = bus.transport("a"), bus.transport("b"), bus.transport("watcher")
    assert one_key_two_tokens(a, b, watcher, lambda until=None: None) == ONE_KEY_TWO_TOKENS


@pytest.mark.slow
def test_zenoh_tells_a_key_once_and_its_going_with_its_last_token():
    """What the memory bus copies, on real Zenoh sessions on loopback."""
    from ramps.runtime.transport import ZenohTransport

    def session(connect: list[str], listen: list[str]) -> ZenohTransport:
        s = load_settings(flags={"team": "same-name", "multicast": False, "connect": connect}, environ={},
                          default_robot=False)
        return ZenohTransport.open(s, listen=listen)

    def wait(until: Callable[[], object] | None = None) -> None:
        end = time.monotonic() + (5.0 if until else 1.0)
        while time.monotonic() < end and not (until and until()):
            time.sleep(0.02)

    a = session([], ["tcp/127.0.0.1:0"])
    b = session(a.locators(), ["tcp/127.0.0.1:0"])
    watcher = session(a.locators() + b.locators(), [])
    try:
        wait(lambda: len(watcher.peers()) == 2)
        assert one_key_two_tokens(a, b, watcher, wait) == ONE_KEY_TWO_TOKENS
    finally:
        for t in (watcher, b, a):
            t.close()
