"""Which teammates' load reports a node hears (``Membership.widen``,
``ramps.runtime.node_team``): real nodes and real clients on the memory bus.

A robot no application submits to hears no teammate's periodic report (its
own name's only: another node under it), so what an idle robot receives does
not grow with the team; a robot whose application connects subscribes to
them all and fetches every teammate's newest report before it places its
first program; ``sees`` in every robot's report still counts its live
teammates."""

from __future__ import annotations

from ramps.core.config import RampsConfig
from ramps.runtime import keys
from ramps.testing.memory import MemoryTeam

#: longer than the core's ``max_report_age``: the reports of the instant every
#: teammate sent when a robot joined have aged out of its view by then
IDLE = RampsConfig().max_report_age + 5.0


def periodic_from_others(team: MemoryTeam, robot: str) -> dict[str, int]:
    """The teammates' periodic reports ``robot``'s transport heard, by key."""
    own = keys.load(team.team, robot)
    return {k: n for k, n in team.bus.transports[robot].heard.items()
            if k.startswith(keys.load(team.team, "")) and not k.endswith("/now") and k != own}


def robots(n: int, slow_first: bool = False) -> dict[str, tuple[int, float]]:
    return {f"r{i}": ((1, 1.0) if slow_first and i == 1 else (4, 4.0)) for i in range(1, n + 1)}


def test_a_robot_that_places_nothing_hears_no_teammates_periodic_reports() -> None:
    from ramps.runtime.client import Team
    from ramps.runtime.settings import load_settings

    team = MemoryTeam(robots(5))
    s = load_settings(flags={"team": team.team}, environ={}, default_robot=False)
    # an application that only watches (``ramps top``): it hears them all, and makes no robot an origin
    watcher = Team(s, robot="r3", timeout=1.0, transport=team.bus.transport("top"), clock=team.clock, submits=False)
    try:
        team.run(IDLE)
        for name, rt in team.nodes.items():
            assert not rt.membership.wide, name
            assert periodic_from_others(team, name) == {}, name
            assert team.bus.transports[name].heard[keys.load(team.team, name)] >= IDLE - 1  # its own
            # each node still answers a query for its newest report
            assert rt.membership.newest is not None
        assert team.bus.transports["top"].heard[keys.load(team.team, "r5")] > 0
        assert {r.robot: r.sees for r in watcher.status().robots} == {n: 4 for n in team.nodes}
    finally:
        watcher.close()
        team.close()


def test_an_origin_fetches_its_teammates_reports_before_its_first_placement() -> None:
    """r1 is slow and has heard nothing of its teammates for longer than a
    report stays fresh: its view holds only itself. Its application connects
    and submits at once; r1 subscribes to the periodic reports, queries every
    teammate's newest, and its first burst goes across the team."""
    team = MemoryTeam(robots(5, slow_first=True))
    app = None
    try:
        team.run(IDLE)
        r1 = team.nodes["r1"]
        assert r1.node.view.candidates(r1._clock()) == ["r1"]  # blind, were it to place now
        app = team.connect("r1")
        futs = [app.options(work=20.0).submit("echo", x=i) for i in range(8)]  # before the node ran at all
        team.run(60.0, until=lambda: all(f.done() for f in futs))
        assert [f.result(0)["x"] for f in futs] == list(range(8))
        hosts = {f.host for f in futs}
        assert len(hosts) >= 3 and hosts - {"r1"}, hosts  # across the team, not all on the slow origin
        assert r1.membership.wide and r1.membership.ready
        assert r1.membership.fetched == 5  # every robot's newest, its own included
        assert team.bus.transports["r1"].queried == [keys.load(team.team)]  # one query, once
        assert sorted(periodic_from_others(team, "r1")) == [keys.load(team.team, f"r{i}") for i in range(2, 6)]
        for name in ("r2", "r3", "r4", "r5"):  # hosts, not origins: still no periodic reports
            assert periodic_from_others(team, name) == {}, name
    finally:
        if app is not None:
            app.close()
        team.close()


def test_a_request_waits_for_the_views_when_it_comes_before_the_application_token() -> None:
    """A program submitted on the wire with no application token before it
    (an older client) waits for the query too."""
    import msgspec

    from ramps.core.messages import SubmitProgram, encode

    team = MemoryTeam(robots(4, slow_first=True))
    try:
        team.run(IDLE)
        t = team.bus.transport("old")
        t.subscribe(keys.client(team.team, "old"), lambda data: None)
        for i in range(6):
            t.put(keys.inbox(team.team, "r1"), encode("old", SubmitProgram(
                client="old", request_id=i + 1, program="echo", args=msgspec.msgpack.encode({"x": i}), work=20.0)))
        team.run(30.0)
        r1 = team.nodes["r1"]
        assert r1.membership.ready and r1.membership.fetched == 4
        placed = {h for n, rt in team.nodes.items() for h in [n] if team.pools[n].ran}
        assert placed - {"r1"}, placed
    finally:
        team.close()


def test_every_robot_reports_the_live_teammates_it_sees() -> None:
    """``ramps status``'s "sees": an origin counts the teammates it could
    place on, the others the teammates whose liveliness they hold; both
    drop a killed robot."""
    team = MemoryTeam(robots(5))
    app = team.connect("r1")
    try:
        team.run(IDLE)
        rows = {r.robot: r for r in app.status().robots}
        assert {n: rows[n].sees for n in team.nodes} == {n: 4 for n in team.nodes}
        assert team.nodes["r1"].membership.wide and not team.nodes["r2"].membership.wide
        team.kill("r5")
        team.run(3.0)
        rows = {r.robot: r for r in app.status().robots}
        assert {n: rows[n].sees for n in ("r1", "r2", "r3", "r4")} == {n: 3 for n in ("r1", "r2", "r3", "r4")}
    finally:
        app.close()
        team.close()


def test_what_an_idle_robot_hears_does_not_grow_with_the_team() -> None:
    """Messages a second an idle robot's node receives, one origin in the
    team, at 10 and 40 robots: its own periodic report and the origin's link
    probes, whatever the team's size (the origin's own grow with it)."""
    per_s = {}
    for n in (10, 40):
        team = MemoryTeam(robots(n))
        app = team.connect("r1")
        try:
            team.run(IDLE)
            before = {name: sum(t.heard.values()) for name, t in team.bus.transports.items()}
            team.run(20.0)
            heard = {name: (sum(t.heard.values()) - before[name]) / 20.0 for name, t in team.bus.transports.items()}
            per_s[n] = (max(heard[f"r{i}"] for i in range(2, n + 1)), heard["r1"])
        finally:
            app.close()
            team.close()
    (idle10, origin10), (idle40, origin40) = per_s[10], per_s[40]
    # its own report every period, one probe from the one origin every probe period
    bound = 1.0 / 1.0 + 1 / RampsConfig().probe_period + 0.1
    assert idle10 <= bound and idle40 <= bound, per_s
    assert origin40 > 3 * origin10  # the origin hears every teammate's reports
