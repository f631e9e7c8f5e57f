"""A teammate heard one way only (a split Zenoh session, ``ramps.core.oneway``):
noted once, after ``ONE_WAY_AFTER``, from either side, and noted again when it
ends; never for a teammate that is simply gone or frozen. Through the real core
(``FakeTeam``): reports are published by hand, liveliness is the transport's
``PeerAlive``/``PeerLost``."""

from __future__ import annotations

from corehelpers import report, submit

from ramps.core.events import ApplicationHere, PeerAlive, PeerLost
from ramps.core.loadview import LoadView
from ramps.core.oneway import ONE_WAY_AFTER, OneWay
from ramps.testing import FakeTeam


def team_with_origin() -> FakeTeam:
    team = FakeTeam({"o": (4, 1.0), "a": (4, 1.0), "b": (4, 1.0)})
    for other in ("a", "b"):
        team.handle("o", PeerAlive(robot=other))
    team.handle("o", ApplicationHere())  # an application submits here: o hears periodic reports
    team.publish()
    return team


def every_period(team: FakeTeam, until: float, publishing: tuple[str, ...]) -> None:
    """Advance to ``until``, the ``publishing`` robots reporting every second."""
    t = team.now
    while t < until:
        t = min(until, t + 1.0)
        team.advance(t)
        team.now = t
        if publishing:
            team.publish(*publishing)


def test_a_teammate_alive_whose_reports_stop_is_noted_once_and_again_when_they_come_back() -> None:
    team = team_with_origin()
    every_period(team, ONE_WAY_AFTER - 5, ("a", "b"))
    every_period(team, ONE_WAY_AFTER + 35, ("b",))  # a's reports stop reaching o; its token stays
    noted = team.notes("one_way")
    assert [n.robot for n in noted] == ["a"]
    assert "no load report" in noted[0].detail
    every_period(team, ONE_WAY_AFTER + 60, ("b",))
    assert len(team.notes("one_way")) == 1  # once
    every_period(team, ONE_WAY_AFTER + 75, ("a", "b"))
    assert [n.robot for n in team.notes("two_way")] == ["a"]


def test_reports_from_a_teammate_whose_liveliness_is_gone_are_noted() -> None:
    # the other side of the split: its reports still arrive, its token does not come back
    team = team_with_origin()
    every_period(team, 5.0, ("a", "b"))
    team.handle("o", PeerLost(robot="a"))
    every_period(team, ONE_WAY_AFTER + 20, ("a", "b"))
    [noted] = team.notes("one_way")
    assert noted.robot == "a" and "liveliness token has been gone" in noted.detail


def test_a_teammate_gone_or_frozen_or_merely_quiet_is_not_noted() -> None:
    team = team_with_origin()
    every_period(team, 5.0, ("a", "b"))
    team.handle("o", PeerLost(robot="a"))  # crashed: no token, no reports
    every_period(team, 12.0, ("b",))
    team.handle("o", PeerLost(robot="b"))  # frozen past its lease, then back before long
    every_period(team, 20.0, ())
    team.handle("o", PeerAlive(robot="b"))
    every_period(team, ONE_WAY_AFTER + 40, ("b",))
    assert not team.notes("one_way")


def test_a_robot_that_places_nothing_does_not_expect_periodic_reports() -> None:
    team = FakeTeam({"o": (4, 1.0), "a": (4, 1.0)})
    team.handle("o", PeerAlive(robot="a"))  # o places nothing: it hears only reports of the instant
    every_period(team, ONE_WAY_AFTER * 3, ())
    assert not team.notes("one_way")
    submit(team)  # now it places: from then on it counts, not from a's arrival long ago
    team.deliver()
    every_period(team, team.now + ONE_WAY_AFTER / 2, ())
    assert not team.notes("one_way")
    every_period(team, team.now + ONE_WAY_AFTER, ())
    assert [n.robot for n in team.notes("one_way")] == ["a"]


def test_the_detector_alone_against_a_view() -> None:
    view = LoadView("o", cores=4, speed=1.0)
    ow = OneWay("o")
    ow.peer_alive("o", 0.0)  # itself: never
    ow.peer_alive("a", 0.0)
    assert ow.check(view, 0.5, True) == []  # it hears periodic reports from now
    view.on_report(report("a", seq=1), 1.0)
    assert ow.check(view, 10.0, True) == []
    assert [n.what for n in ow.check(view, 1.0 + ONE_WAY_AFTER + 1, True)] == ["one_way"]
    view.on_report(report("a", seq=2), 40.0)
    assert [n.what for n in ow.check(view, 41.0, True)] == ["two_way"]
    assert ow.check(view, 42.0, True) == []


def test_a_node_logs_a_teammate_heard_one_way_only(caplog):
    """Real drivers on the memory bus: r2's messages stop reaching r1 (its token stays);
    r1, which places programs for an application, warns once, and again when it ends."""
    import logging

    from ramps.testing.memory import MemoryTeam

    team = MemoryTeam({"r1": (2, 1.0), "r2": (2, 1.0)})
    app = team.connect("r1")
    try:
        team.run(5.0)
        caplog.set_level(logging.WARNING, logger="ramps.node")
        team.bus.split("r2", "r1")
        team.run(ONE_WAY_AFTER + 10.0)
        warned = [r.getMessage() for r in caplog.records if "heard one way only" in r.getMessage()]
        assert len(warned) == 1 and "teammate r2" in warned[0] and "no load report" in warned[0], warned
        team.bus.restore("r2")
        team.run(10.0)
        assert any("r2 is heard both ways again" in r.getMessage() for r in caplog.records)
    finally:
        app.close()
        team.close()


def test_the_metrics_gauge_counts_teammates_heard_one_way_now():
    from ramps.core.events import Note
    from ramps.runtime.metrics import NodeMetrics

    m = NodeMetrics("r1", "t")

    def value() -> float | None:
        return m.registry.get_sample_value("ramps_one_way_teammates", {"robot": "r1"})

    assert value() == 0
    m.on_action(Note(what="one_way", robot="r2"), None)
    m.on_action(Note(what="one_way", robot="r3"), None)
    assert value() == 2
    m.on_action(Note(what="two_way", robot="r2"), None)
    assert value() == 1


def test_a_node_set_to_restart_when_split_leaves_the_team_and_says_why():
    """``restart_when_split``: r1, hearing r2 one way only, hands back what it runs and leaves
    (the CLI then exits with 75 for its supervisor); without it, r1 stays."""
    from ramps.testing.memory import MemoryTeam

    for restart in (False, True):
        team = MemoryTeam({"r1": (2, 1.0), "r2": (2, 1.0)}, settings={"restart_when_split": restart})
        app = team.connect("r1")
        try:
            team.run(5.0)
            team.bus.split("r2", "r1")
            team.run(ONE_WAY_AFTER + 10.0)
            r1 = team.nodes["r1"]
            if restart:
                assert r1.wait(0) and "teammate r2 is heard one way only" in r1.split
                assert not team.nodes["r2"].wait(0) and not team.nodes["r2"].split  # r2 hears r1: it stays
            else:
                assert not r1.wait(0) and r1.split == ""
        finally:
            app.close()
            team.close()


def test_the_split_experiment_reads_ss_lines():
    from ramps.lab.split import parse_ss

    text = ("0      0      10.201.1.2:7447  10.201.1.254:37094\n"
            "0      0      10.201.1.2:44398   10.201.1.1:7447 \n\n")
    assert parse_ss(text) == [("10.201.1.2", "7447", "10.201.1.254", "37094"),
                              ("10.201.1.2", "44398", "10.201.1.1", "7447")]
