"""Fleets in the simulator: heartbeats and load reports by mailbox
(``ramps.sim.fleet``), read by each receiver in batches (``Node.handle_all``)."""

from __future__ import annotations

import random

import msgspec

from ramps.bench.simulator import large_team
from ramps.core.config import RampsConfig
from ramps.core.events import Received
from ramps.core.messages import LoadReport
from ramps.core.node import Node
from ramps.sim.engine import Simulator
from ramps.sim.fleet import GRID
from ramps.sim.scenario import FaultSpec, NetworkSpec


def fleet(robots: int = 80, programs: int = 400, origins: int = 4, **changes) -> Simulator:
    return Simulator(msgspec.structs.replace(large_team(robots, programs, origins), **changes))


def test_only_a_team_larger_than_the_placement_sample_uses_mailboxes() -> None:
    sample = RampsConfig().placement_sample
    assert Simulator(large_team(sample, 100, 2)).mail is None
    assert Simulator(large_team(sample + 1, 100, 2)).mail is not None


def test_a_fleet_delivers_every_program_once_with_its_traffic_in_batches() -> None:
    sim = fleet()
    res = sim.run()
    assert res.completed == 400 and res.lost == 0 and res.duplicated == 0
    assert sim.mail is not None and sim.mail.read > 0 and sim.mail.lost == 0
    # one event per receiver and grid step, for many messages each
    assert sim.mail.batches <= 4 * res.end_time / GRID + 4
    assert sim.mail.read > 10 * sim.mail.batches


def test_a_fleet_run_is_the_same_for_the_same_seed() -> None:
    a, b = fleet().run(), fleet().run()
    assert [(p.program_id, p.host, p.delivered_at) for p in a.programs] == \
        [(p.program_id, p.host, p.delivered_at) for p in b.programs]
    assert a.events == b.events


def test_a_frozen_host_in_a_fleet_is_written_off_by_its_silence() -> None:
    """Without liveliness only the heartbeats, read from mailboxes, tell a
    frozen host's origins: its programs run again elsewhere, each delivered once."""
    sc = large_team(80, 400, 4)
    sc = msgspec.structs.replace(sc, network=NetworkSpec(liveliness=False),
                                 faults=[FaultSpec(at=8.0, robot="w10", kind="freeze")])
    res = Simulator(sc).run()
    assert res.completed == 400 and res.lost == 0 and res.duplicated == 0
    assert not any(p.host == "w10" for p in res.programs)
    assert sum(s.host_failures for s in res.statistics) > 0


def test_handle_all_is_handle_of_each_in_order() -> None:
    def node() -> Node:
        return Node("a", cores=4, speed=1.0, rng=random.Random(1), submits=True)

    reports = [LoadReport(robot=f"r{i}", incarnation=1, seq=s, cores=4, speed=1.0, cpu_busy=float(i),
                          runnable=float(i), ramps_running=0, ramps_avg=0.0, accepted_total=0, finished_total=0)
               for s in (1, 2) for i in range(3)]
    one, each = node(), node()
    batch = one.handle_all([Received(sender=r.robot, msg=r) for r in reports], 5.0)
    singly = [a for r in reports for a in each.handle(Received(sender=r.robot, msg=r), 5.0)]
    assert batch == singly
    assert one.view.reports_received == each.view.reports_received
    assert {r: one.view.report_of(r).seq for r in ("r0", "r1", "r2")} == {r: 2 for r in ("r0", "r1", "r2")}


def test_a_crashed_host_in_a_fleet_loses_the_heartbeats_waiting_for_it_and_its_programs_run_again() -> None:
    sc = large_team(80, 400, 4)
    sc = msgspec.structs.replace(sc, faults=[FaultSpec(at=8.0, robot="w10", kind="crash"),
                                             FaultSpec(at=30.0, robot="w10", kind="recover")])
    sim = Simulator(sc)
    res = sim.run()
    assert res.completed == 400 and res.lost == 0 and res.duplicated == 0
    assert sum(s.host_failures for s in res.statistics) > 0
    assert sim.mail is not None and res.messages_dropped >= sim.mail.lost
