"""Two nodes under one robot name (machines cloned from one disk image share
their host name, the default name; a second ``ramps node`` started by
mistake): the one that started later leaves with a clear error, whatever its
random draw, and the one already running stays with its programs and
clients; a restarted node's previous process, whose last reports may still
be on their way, is not a clash. The core's rule (``ramps.core.identity``),
then the real driver and core over the in-memory transport."""

from __future__ import annotations

import logging
import random
import re
import time
from typing import Any, Callable

import msgspec
import pytest

from ramps.core.events import NameTaken, Received
from ramps.core.identity import DRAW_MASK, SAME_NAME_SPAN, new_incarnation, started_at
from ramps.core.messages import encode
from ramps.core.node import Node
from ramps.runtime import keys
from ramps.runtime.node import NodeRuntime
from ramps.runtime.settings import load_settings
from ramps.testing.memory import MemoryBus, MemoryPool, MemoryTeam, StillSampler

#: a start time (Unix seconds) for the core's tests
T0 = 1_800_000_000.0


def clone(team: MemoryTeam, robot: str, draw: int | None = None, *, key: str | None = None) -> NodeRuntime:
    """One more node named ``robot``, started now on its own transport, its
    incarnation drawn as a node draws it with the random bits ``draw``
    (None: the node draws them). ``key``: its name in ``team.nodes`` and
    ``team.pools`` (default ``<robot>-clone``)."""
    key = key or f"{robot}-clone"
    s = load_settings(flags={"robot": robot, "team": team.team, "cores": 2, "speed": 1.0}, environ={})

    def pool(*a: Any, **kw: Any) -> MemoryPool:
        p = team.pools[key] = MemoryPool(*a, **kw)
        return p

    rt = NodeRuntime(s, transport=team.bus.transport(key), clock=team.clock, worker_pool=pool,
                     load_sampler=StillSampler,
                     incarnation=None if draw is None else new_incarnation(team.clock.time(), draw))
    rt.start(threaded=False)
    team.nodes[key] = rt
    return rt


# ---------------------------------------------------------------- the core's rule

def test_an_incarnation_is_the_start_time_then_the_draw():
    assert new_incarnation(T0, DRAW_MASK) < new_incarnation(T0 + 0.001, 0)  # later wins over any draw
    assert new_incarnation(T0, 1) < new_incarnation(T0, 2)  # the same millisecond: the draw
    assert started_at(new_incarnation(T0 + 0.25, 12345)) == T0 + 0.25
    assert started_at(random.Random(0).getrandbits(48)) is None  # ramps 0.1.0's: 48 random bits
    assert new_incarnation(T0, DRAW_MASK).bit_length() <= 63  # a signed 64-bit integer wherever it is kept


def _report(node: Node, seq: int) -> Any:
    return msgspec.structs.replace(node.current_report(), seq=seq)


@pytest.mark.parametrize("first_draw, later_draw, gap", [(0, DRAW_MASK, 2.0), (DRAW_MASK, 0, 2.0), (7, 3, 0.0)])
def test_both_nodes_decide_that_the_later_one_leaves(first_draw, later_draw, gap):
    """Each node hears the other's reports; whichever hears first, both
    decide the same: the node that started later leaves (at the same
    millisecond, ``gap`` 0: the larger draw)."""
    first = Node("r2", cores=2, speed=1.0, rng=random.Random(0), incarnation=new_incarnation(T0, first_draw))
    later = Node("r2", cores=2, speed=1.0, rng=random.Random(1), incarnation=new_incarnation(T0 + gap, later_draw))
    told: dict[str, list] = {"first": [], "later": []}
    for k, now in enumerate([10.0, 10.2, 11.0, 12.0]):
        for name, me, other in (("first", first, later), ("later", later, first)):
            out = me.handle(Received(sender="r2", msg=_report(other, k + 1)), now)
            told[name] += [a for a in out if isinstance(a, NameTaken)]
    later_leaves = gap > 0 or later_draw > first_draw
    assert told == {"first": [NameTaken(other=later.incarnation, leave=not later_leaves)],
                    "later": [NameTaken(other=first.incarnation, leave=later_leaves)]}
    for me in (first, later):  # neither took the other's load for its own
        assert me.view.report_of("r2") is None or me.view.report_of("r2").incarnation == me.incarnation


def test_the_last_reports_of_a_previous_process_together_are_no_clash():
    old = Node("r2", cores=2, speed=1.0, rng=random.Random(0), incarnation=new_incarnation(T0, 5))
    new = Node("r2", cores=2, speed=1.0, rng=random.Random(1), incarnation=new_incarnation(T0 + 4, 1))
    out = new.handle(Received(sender="r2", msg=_report(old, 41)), 10.0)
    out += new.handle(Received(sender="r2", msg=_report(old, 42)), 10.0 + SAME_NAME_SPAN / 2)
    out += new.handle(Received(sender="r2", msg=_report(old, 41)), 20.0)  # the same report, again
    assert not [a for a in out if isinstance(a, NameTaken)]
    assert new.same_name.seen() == {old.incarnation: 41}
    assert new.handle(Received(sender="r2", msg=_report(old, 43)), 20.0) == [NameTaken(other=old.incarnation,
                                                                                       leave=True)]


# ---------------------------------------------------------------- real nodes, in memory

LEAVE_TEXT = re.compile(r"robot name 'r2' is taken in team 'mem' by another node listening on memory/r2, started at "
                        r"\d{4}-\d\d-\d\d \d\d:\d\d:\d\d UTC \((\d+\.\d) s before this one, by the two machines' clocks\); "
                        r"give each machine its own robot name: --robot NAME or RAMPS_ROBOT=NAME \(the default name "
                        r"is the host name, which machines cloned from one disk image share\)$")


@pytest.mark.parametrize("first_draw, newcomer_draw", [(0, DRAW_MASK), (DRAW_MASK, 0)])
def test_the_running_node_stays_and_the_newcomer_leaves_whatever_it_drew(first_draw, newcomer_draw, caplog):
    """r2 runs with a client's program in flight; a second node starts under
    its name: it leaves within 3 s saying why, with either draw, and r2 keeps
    its program and its client."""
    caplog.set_level(logging.ERROR, logger="ramps.node")
    team = MemoryTeam({"r1": (2, 1.0)})
    client = None
    try:
        first = clone(team, "r2", first_draw, key="r2")
        team.run(3.0)
        client = team.connect("r2")
        futs = [client.options(work=2.0).submit("echo", x=i) for i in range(3)]  # on r1 and r2
        team.run(1.0, complete=False)
        assert {team.pools["r1"].jobs and "r1", team.pools["r2"].jobs and "r2"} == {"r1", "r2"}
        team.run(1.0, complete=False)
        newcomer = clone(team, "r2", newcomer_draw)
        assert newcomer.incarnation > first.incarnation
        started = team.clock.t
        team.run(5.0, complete=False, until=lambda: newcomer.wait(0))
        assert newcomer.wait(0) and team.clock.t - started < 3.0, "refused within 3 s"
        m = LEAVE_TEXT.match(newcomer.name_taken)
        assert m and m.group(1) == "5.0", newcomer.name_taken
        assert not first.wait(0) and first.name_taken == ""
        said = [r.getMessage() for r in caplog.records]
        assert any(t.endswith("this node started later and leaves the team") for t in said)
        told = [t for t in said if "another node of team mem joined under this robot's name listening on "
                "memory/r2-clone, started at " in t and "(5.0 s after this one, by the two machines' clocks): it "
                "leaves the team and this node stays" in t]
        assert len(told) == 1, said  # by its token or its reports, whichever came first, once
        team.run(5.0, until=lambda: all(f.done() for f in futs))
        assert [f.result(0) for f in futs] == [{"x": i} for i in range(3)]
        later = client.submit("echo", x=9)  # r2, the node that stayed, serves the next call
        team.run(3.0, until=later.done)
        assert later.result(0) == {"x": 9}
        assert {r.robot: r.alive for r in client.status().robots} == {"r1": True, "r2": True}
    finally:
        if client is not None:
            client.close()
        team.close()


def test_the_running_node_says_a_later_node_leaves_from_its_token_alone(caplog):
    """The later node may hear the running one's reports and leave before the
    running one has heard two of its own: its ``where`` token then tells the
    running node, once, and tokens of earlier nodes (a previous process) tell
    it nothing."""
    from ramps.runtime.node_name import SameName
    from ramps.runtime.node_trace import NodeTrace
    from ramps.testing.memory import FakeClock

    caplog.set_level(logging.ERROR, logger="ramps.node")
    mine, later, earlier = (new_incarnation(T0 + dt, 7) for dt in (0.0, 2.5, -60.0))
    names = SameName("mem", "r2", NodeTrace("r2", FakeClock()))
    names.incarnation = mine
    names.on_where(keys.where("mem", "r2", mine, ["tcp/10.0.0.2:7447"]), True)  # its own
    names.on_where(keys.where("mem", "r2", earlier, ["tcp/10.0.0.2:7447"]), True)
    assert caplog.records == []
    names.on_where(keys.where("mem", "r2", later, ["tcp/10.0.0.9:7447"]), True)
    said = [r.getMessage() for r in caplog.records]
    assert len(said) == 1 and "joined under this robot's name listening on tcp/10.0.0.9:7447" in said[0], said
    assert "(2.5 s after this one, by the two machines' clocks): it leaves the team and this node stays" in said[0]
    assert names.clash(NameTaken(other=later, leave=False)) is False  # its reports came after all
    assert len(caplog.records) == 1 and names.taken == ""


def test_a_node_draws_its_incarnation_from_its_start_time():
    team = MemoryTeam({"r1": (2, 1.0)})
    try:
        rt = clone(team, "r2")
        assert started_at(rt.incarnation) == int(team.clock.time() * 1000) / 1000
    finally:
        team.close()


def test_a_restarted_node_joins_though_its_previous_process_reports_arrive():
    """r2 dies; the supervisor starts it again, drawing a smaller random
    part; two last reports of the dead process arrive after the new one
    started: not a clash, and the new r2 serves."""
    team = MemoryTeam({"r1": (2, 1.0)})
    client = None
    try:
        old = clone(team, "r2", DRAW_MASK, key="r2-old")
        team.run(3.0)
        last = old.reports.last
        stale = [last, msgspec.structs.replace(last, seq=last.seq + 1)]
        team.kill("r2-old")
        team.run(0.5)
        new = clone(team, "r2", 0, key="r2")
        assert new.incarnation > old.incarnation  # a later start: larger, though it drew less
        stray = team.bus.transport("stray")
        for report in stale:  # still on their way
            stray.put(keys.load(team.team, "r2"), encode("r2", report))
        team.run(5.0)
        assert new.node.same_name.seen() == {old.incarnation: last.seq}  # heard, and not taken for a clash
        assert not new.wait(0) and new.name_taken == ""
        client = team.connect("r1")
        fut = client.submit("echo", x=1)
        team.run(3.0, until=fut.done)
        assert fut.result(0) == {"x": 1}
        assert {r.robot: r.alive for r in client.status().robots} == {"r1": True, "r2": True}
        assert team.nodes["r1"].node.view.report_of("r2").incarnation == new.incarnation
    finally:
        if client is not None:
            client.close()
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
        other = clone(team, "r2", 99)  # started later than r2: it leaves
        team.run(5.0, complete=False)
        assert other.wait(0) and other.name_taken, "the clone left"
        assert {r.robot: r.alive for r in client.status().robots} == {"r1": True, "r2": True}
        team.run(1.0)
        assert fut.result(timeout=5) == {"x": 1}
    finally:
        client.close()
        team.close()


HOLD = """
import sys, time
from ramps.runtime.store import OriginStore
store = OriginStore(sys.argv[1], team="lab", robot="r2")
print("held", flush=True)
time.sleep(60)
"""


def test_a_second_node_of_a_robot_on_one_machine_is_refused_before_it_touches_the_record(tmp_path, monkeypatch):
    """A second ``ramps node`` started by mistake on the robot's own machine
    finds the running node's record locked: exit 2, saying why, before it
    reads the record or joins the team; once the first process is gone (even
    killed), the record is free again."""
    import signal
    import subprocess
    import sys

    from typer.testing import CliRunner

    from ramps.cli import app
    from ramps.errors import ConfigError
    from ramps.runtime.store import OriginStore

    first = subprocess.Popen([sys.executable, "-c", HOLD, str(tmp_path)], stdout=subprocess.PIPE, text=True)
    try:
        assert first.stdout.readline().strip() == "held"
        with pytest.raises(ConfigError) as refused:
            OriginStore(tmp_path, team="lab", robot="r2")
        assert str(refused.value) == (
            f"a node of robot 'r2' of team 'lab' already runs on this machine (pid {first.pid}) and holds its record "
            f"{tmp_path / 'lab' / 'r2.sqlite'}: give this node its own robot name (--robot NAME or "
            f"RAMPS_ROBOT=NAME), or stop the other one first")
        OriginStore(tmp_path, team="lab", robot="r3").close()  # another robot's record is its own
        monkeypatch.setattr(signal, "signal", lambda *a: None)  # the node's handlers stay out of pytest
        monkeypatch.setattr("ramps.runtime.node.prioritize", lambda nice: True)
        monkeypatch.setattr("ramps.runtime.node.ZenohTransport.open", pytest.fail)  # refused before joining
        res = CliRunner().invoke(app, ["node", "--robot", "r2", "--team", "lab", "--no-multicast", "--speed", "1",
                                       "--cores", "1", "--state-dir", str(tmp_path)], env={"COLUMNS": "400"})
        assert res.exit_code == 2, res.output
        assert f"error: a node of robot 'r2' of team 'lab' already runs on this machine (pid {first.pid})" in res.output
    finally:
        first.kill()
        first.wait()
        first.stdout.close()
    store = OriginStore(tmp_path, team="lab", robot="r2")  # the kernel dropped the dead process's lock
    store.close()


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
def test_a_clone_on_the_network_is_refused_and_the_running_node_serves(tmp_path):
    """Real ``ramps node`` processes over Zenoh on loopback: r2 runs a
    client's programs; a second node named r2 (its own record, as on a
    cloned machine) joins, then exits 2 saying why (1.7 s after joining on
    the development VM; in virtual time above, within 3 s); r2's programs
    finish and it serves the next call."""
    from runtime_team import LocalTeam, assert_no_leftovers, wait_for

    from ramps.runtime.localteam import free_port

    with LocalTeam(2, tmp_path) as t:
        client = t.client("r2")
        futs = [client.submit("sleepy", seconds=4.0) for _ in range(3)]
        wait_for(lambda: all(f.state == "running" for f in futs), 30, "the programs to run")
        argv = t.node_argv("r2", free_port(), 2, None) + ["--state-dir", "off"]
        clone = t.spawn(argv, name="r2-clone")
        log = t.log_dir / "r2-clone.log"
        wait_for(lambda: log.exists() and "joined team" in log.read_text(), 60, "the clone to join")
        assert clone.wait(timeout=30) == 2, log.read_text()
        text = " ".join(log.read_text().split())
        assert "error: this node left the team: robot name 'r2' is taken in team" in text, text
        # it names where the other node listens, as that node's banner does
        assert f"by another node listening on {t.endpoint('r2')}" in text, text
        assert "give each machine its own robot name: --robot NAME or RAMPS_ROBOT=NAME" in text
        assert t.nodes["r2"].proc.poll() is None
        assert [f.result(timeout=60)["robot"] in ("r1", "r2") for f in futs] == [True] * 3
        assert client.submit("where", x=1).result(timeout=30)["x"] == 1
        assert "it leaves the team and this node stays" in t.logs("r2")
    assert_no_leftovers()


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
