"""Which periodic load reports go on the wire (``ramps.core.cadence``), in
the core and as the simulator's robots send them."""

from __future__ import annotations

import msgspec

from test_report_rate import _report

from ramps.core.cadence import ReportCadence
from ramps.core.config import RampsConfig
from ramps.sim.engine import simulate
from ramps.sim.scenario import ProgramSpec, PublisherSpec, RobotSpec, Scenario


def test_one_report_in_three_goes_and_a_change_goes_at_once() -> None:
    c = ReportCadence()
    quiet = _report()
    went = [t for t in range(10) if c.due(msgspec.structs.replace(quiet, seq=t), float(t), 3.0, 1.0)]
    assert went == [0, 3, 6, 9]
    assert c.due(_report(seq=10, accepted_total=1), 10.0, 3.0, 1.0)  # a program accepted: now
    assert not c.due(_report(seq=11, accepted_total=1, cpu_busy=0.9), 11.0, 3.0, 1.0)  # its load alone: waits


def test_a_period_no_longer_than_the_publishers_sends_every_report() -> None:
    """The paper's teams and a tie (3 s at a 2 s publisher) go at every
    publish, whatever the rounding of the publisher's clock."""
    c = ReportCadence()
    t, went = 0.1, 0
    for _ in range(50):
        went += c.due(_report(), t, 3.0, 2.0)
        t += 2.0
    assert went == 50
    c = ReportCadence()
    assert all(c.due(_report(), 0.3 + k * 1.0, 1.0, 1.0) for k in range(20))


def _team(report_rate: float) -> Scenario:
    return Scenario(name="cadence", seed=3, robots=[RobotSpec(name="w{i}", count=100, cores=1)],
                    programs=[ProgramSpec(count=20, work=2.0, payload=100, result=100, origin="w1", at=1.0)],
                    config=RampsConfig(report_rate=report_rate), publisher=PublisherSpec(period=1.0), until=40.0)


def test_the_simulators_robots_space_their_reports_as_nodes_do() -> None:
    """100 robots publishing every second: with ``report_rate`` 32 a robot's
    periodic report goes every 3 s (as a node's does), so the origin hears
    about a third as many as with the bound off; every program completes."""
    spaced, every = simulate(_team(32.0)), simulate(_team(0.0))
    heard = {name: next(s.reports_received for s in res.statistics if s.robot == "w1")
             for name, res in (("spaced", spaced), ("every", every))}
    assert spaced.completed == every.completed == 20 and not spaced.lost and not spaced.duplicated
    assert 0.25 < heard["spaced"] / heard["every"] < 0.5, heard
