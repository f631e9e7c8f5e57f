"""The real node driver (``NodeRuntime``) and the real core, whole teams of
them, over the in-memory transport with a fake clock and in-process programs
(``ramps.testing.memory``): submit checks, offloading, shutdown handover,
backlog overflow and reconnection, in milliseconds and without processes.
The same behaviours over Zenoh and real processes: tests/test_runtime_e2e.py,
tests/test_busy_node_e2e.py."""

from __future__ import annotations

import msgspec
import pytest

import ramps.runtime.node as rn
from ramps.core.messages import ProgramOutcome, ProgramUpdate, SubmitProgram, decode, encode
from ramps.runtime import keys
from ramps.testing.memory import MemoryTeam


class App:
    """A client on the bus: submits to its robot's node, collects what comes back."""

    def __init__(self, team: MemoryTeam, robot: str, name: str = "app") -> None:
        self.team, self.robot, self.name = team, robot, name
        self.t = team.bus.transport(name)
        self.outcomes: dict[int, list[ProgramOutcome]] = {}
        self.updates: list[ProgramUpdate] = []
        self.t.subscribe(keys.client(team.team, name), self._heard)
        self._rid = 0

    def _heard(self, data: bytes) -> None:
        msg = decode(data).msg
        if isinstance(msg, ProgramOutcome):
            self.outcomes.setdefault(msg.request_id, []).append(msg)
        elif isinstance(msg, ProgramUpdate):
            self.updates.append(msg)

    def submit(self, program: str, *, work: float = 0.0, args: bytes | None = None, **kwargs) -> int:
        self._rid += 1
        data = msgspec.msgpack.encode(kwargs) if args is None else args
        self.t.put(keys.inbox(self.team.team, self.robot),
                   encode(self.name, SubmitProgram(client=self.name, request_id=self._rid, program=program,
                                                   args=data, work=work)), block=True)
        return self._rid

    def done(self, *rids: int) -> bool:
        return all(r in self.outcomes for r in rids)

    def outcome(self, rid: int) -> ProgramOutcome:
        [out] = self.outcomes[rid]  # one outcome per request, never two
        return out


@pytest.fixture
def team():
    t = MemoryTeam({"r1": (1, 1.0), "r2": (4, 4.0), "r3": (4, 4.0)})
    t.run(3.0)  # everyone has heard everyone's reports
    yield t
    t.close()


def test_the_team_forms_over_the_memory_transport(team):
    for name, rt in team.nodes.items():
        assert sorted(rt.node.view.candidates(rt._clock())) == ["r1", "r2", "r3"], name
    assert team.nodes["r1"].endpoints() == ["memory/r1"]


def test_bad_submissions_get_a_clear_error_and_lose_nothing(team):
    clients = team.nodes["r1"].clients  # what checks r1's submissions, its limit on arguments lowered
    clients.s = msgspec.structs.replace(clients.s, max_args_bytes=200)
    app = App(team, "r1")
    good = app.submit("echo", x=1)
    unknown = app.submit("no_such_program", x=1)
    wrong = app.submit("burn", minutes=3)  # not burn's signature
    big = app.submit("echo", x="a" * 1000)
    garbage = app.submit("echo", args=b"\xc1\xc1")  # not msgpack
    last = app.submit("echo", x=2)
    team.run(5.0, until=lambda: app.done(good, unknown, wrong, big, garbage, last))
    assert app.outcome(unknown).error_kind == "refused" and "no_such_program" in app.outcome(unknown).error
    assert app.outcome(wrong).error_kind == "bad_arguments" and "'burn'" in app.outcome(wrong).error
    assert app.outcome(big).error_kind == "bad_arguments" and "limit is 200" in app.outcome(big).error
    assert app.outcome(garbage).error_kind == "bad_arguments"
    for rid, x in ((good, 1), (last, 2)):  # the good ones around them ran, once each
        assert app.outcome(rid).ok and msgspec.msgpack.decode(app.outcome(rid).value) == {"x": x}
    assert len(team.pools["r1"].ran) == 2 and team.nodes["r1"].bad_messages == 0


def test_heavy_programs_are_offloaded_and_each_result_delivered_once(team):
    app = App(team, "r1")
    rids = [app.submit("echo", work=20.0, x=i) for i in range(6)]
    team.run(30.0, until=lambda: app.done(*rids))
    hosts = {app.outcome(r).host for r in rids}
    assert hosts & {"r2", "r3"}  # the slow origin sends work to its faster teammates
    assert [msgspec.msgpack.decode(app.outcome(r).value)["x"] for r in rids] == list(range(6))
    ran = sum(len(p.ran) for p in team.pools.values())
    assert ran == 6  # nothing ran twice
    team.run(5.0)
    assert all(len(v) == 1 for v in app.outcomes.values())


def test_a_node_that_leaves_hands_its_programs_back(team):
    app = App(team, "r1")
    rids = [app.submit("echo", work=20.0, x=i) for i in range(4)]
    team.run(2.0, complete=False, until=lambda: any(team.pools[r].jobs for r in ("r2", "r3")))
    leaving = "r2" if team.pools["r2"].jobs else "r3"
    handed = {pid for pid, _ in team.pools[leaving].jobs}
    assert handed
    team.stop(leaving)  # its programs go back to their origin at once
    assert team.pools[leaving].stopped
    team.run(30.0, until=lambda: app.done(*rids))
    assert all(app.outcome(r).ok and app.outcome(r).host != leaving for r in rids)
    assert sum(app.outcome(r).attempts == 2 for r in rids) == len(handed)  # placed again, once each
    assert [msgspec.msgpack.decode(app.outcome(r).value)["x"] for r in rids] == list(range(4))
    rt1 = team.nodes["r1"]
    assert leaving not in rt1.node.view.candidates(rt1._clock())


def test_the_origin_leaving_tells_its_clients_and_hands_nothing_to_nobody(team):
    app = App(team, "r1")
    rid = app.submit("echo", work=20.0, x=1)
    team.run(2.0, complete=False, until=lambda: any(p.jobs for p in team.pools.values()))
    team.stop("r1")
    assert app.outcome(rid).error_kind == "shutdown" and "r1 shut down" in app.outcome(rid).error
    team.run(5.0)
    assert not any(p.jobs for n, p in team.pools.items() if n != "r1")  # its hosts dropped its program


def test_a_full_backlog_drops_and_counts_and_the_node_stays_up(team, monkeypatch):
    """Messages that find the driver's backlog full are dropped and counted
    (memory stays bounded); what was queued before is handled; the node
    answers the next submission."""
    monkeypatch.setattr(rn, "MAX_BACKLOG_BYTES", 64 * 1024)
    rt = team.nodes["r1"]
    app = App(team, "r1")
    first = app.submit("echo", x=7)  # queued before the flood
    flood = team.bus.transport("flood")
    for _ in range(100):  # 100 KB of garbage before the driver runs again: 63 fit beside the submission
        flood.put(keys.inbox(team.team, "r1"), b"\x00" * 1024)
    assert rt.intake.overflow == 37 and rt.intake.backlog > 63 * 1024
    team.run(3.0, until=lambda: app.done(first))
    assert rt.bad_messages == 63 and rt.intake.backlog == 0  # the rest was read and refused
    after = app.submit("echo", x=8)
    team.run(3.0, until=lambda: app.done(after))
    for rid, x in ((first, 7), (after, 8)):
        assert app.outcome(rid).ok and msgspec.msgpack.decode(app.outcome(rid).value) == {"x": x}
    team.run(1.5)
    assert rt.reports.last.bad_messages == 100  # `ramps status` counts both


def test_a_cut_link_is_healed_and_its_programs_complete_once(team):
    app = App(team, "r1")
    rids = [app.submit("echo", work=20.0, x=i) for i in range(4)]
    team.run(2.0, complete=False, until=lambda: bool(team.pools["r2"].jobs))
    on_r2 = {pid for pid, _ in team.pools["r2"].jobs}
    assert on_r2
    rt1 = team.nodes["r1"]
    team.bus.cut("r2")
    team.run(1.0, complete=False)
    assert "r2" not in rt1.node.view.candidates(rt1._clock())  # its liveliness went
    assert {pid for pid, attempt in team.pools["r3"].jobs if attempt == 2} == on_r2  # placed again at once
    team.bus.restore("r2")
    team.run(30.0, until=lambda: app.done(*rids))
    assert [msgspec.msgpack.decode(app.outcome(r).value)["x"] for r in rids] == list(range(4))
    team.run(5.0)  # late copies (r2 finished what was placed again meanwhile) are not delivered again
    assert all(len(v) == 1 for v in app.outcomes.values())
    assert sum(app.outcome(r).attempts == 2 for r in rids) == len(on_r2)
    assert "r2" in rt1.node.view.candidates(rt1._clock())  # seen again
    assert team.nodes["r2"].awake.stalls == 0  # a cut is not a stall


def test_a_stall_is_taken_out_of_the_core_clock(team):
    """A driver that wakes long after it meant to (frozen): the fake clock
    jumps, the driver counts a stall and the core does not see the time."""
    rt = team.nodes["r2"]
    team.run(1.0)
    before = rt._clock()
    team.clock.advance(rt.s.lease_ms / 1000.0 * 3)
    rt.step()
    assert rt.awake.stalls == 1 and rt._clock() - before < 1.0


def test_the_real_client_over_the_memory_transport(team):
    """``ramps.runtime.client.Team`` (what ``ramps.connect()`` returns) on the
    same bus: its submission runs on the team and its future resolves once;
    a node that leaves fails its pending programs at the client."""
    from ramps.errors import ProgramLost

    client = team.connect("r1")
    try:
        assert client.robot == "r1"
        futs = [client.submit("echo", x=i) for i in range(3)]
        team.run(5.0, until=lambda: all(f.done() for f in futs))
        assert [f.result(0) for f in futs] == [{"x": i} for i in range(3)]
        pending = client.options(work=20.0).submit("echo", x=9)
        team.run(1.0, complete=False)
        team.stop("r1")  # the origin leaves: the program is lost, and the client is told why
        with pytest.raises(ProgramLost, match="shut down"):
            pending.result(1.0)
    finally:
        client.close()


def test_the_memory_bus_behaves_as_zenoh_does_for_the_driver():
    """Key expressions match as Zenoh's do; liveliness comes with history,
    goes on undeclare, close and cut, and comes back on restore; a cut
    transport still hears itself and nobody else."""
    from ramps.testing.memory import MemoryBus

    bus = MemoryBus()
    a, b = bus.transport("a"), bus.transport("b")
    heard: list[tuple[str, str, bytes]] = []
    alive: list[tuple[str, str, bool]] = []
    a.subscribe("t/msg/a", lambda d: heard.append(("a", "t/msg/a", d)))
    b.subscribe("t/load/*", lambda d: heard.append(("b", "t/load/*", d)))
    token_a = a.declare_token("t/alive/a")
    b.subscribe_liveliness("t/alive/*", lambda k, up: alive.append(("b", k, up)), history=True)
    a.subscribe_liveliness("t/alive/**", lambda k, up: alive.append(("a", k, up)), history=False)
    assert alive == [("b", "t/alive/a", True)]  # history: the token already there
    b.declare_token("t/alive/b")
    assert alive[-1] == ("a", "t/alive/b", True)
    b.put("t/msg/a", b"1")
    a.put("t/load/a", b"2")
    b.put("t/msg/c", b"3")  # nobody's key
    assert heard == [("a", "t/msg/a", b"1"), ("b", "t/load/*", b"2")]
    assert b.publisher("t/msg/a").matching() and not b.publisher("t/msg/zz").matching()
    with pytest.raises(ValueError, match="already"):
        bus.transport("a")
    alive.clear()
    bus.cut("a")
    assert sorted(alive) == [("a", "t/alive/b", False), ("b", "t/alive/a", False)]
    heard.clear()
    b.put("t/msg/a", b"lost")
    a.put("t/msg/a", b"self")  # a process hears its own subscribers while cut
    assert heard == [("a", "t/msg/a", b"self")] and not b.publisher("t/msg/a").matching()
    assert bus.lost == 0 and a.peers() == [] and b.peers() == []
    alive.clear()
    bus.restore("a")
    assert sorted(alive) == [("a", "t/alive/b", True), ("b", "t/alive/a", True)]
    alive.clear()
    token_a.undeclare()  # a session's own liveliness subscribers see its own tokens, as in Zenoh
    assert sorted(alive) == [("a", "t/alive/a", False), ("b", "t/alive/a", False)]
    alive.clear()
    bus.kill("b")  # its tokens go; it hears nothing more
    assert alive == [("a", "t/alive/b", False)]
    heard.clear()
    a.put("t/load/x", b"gone")
    assert heard == [] and b.closed
