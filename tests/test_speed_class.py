"""Robots of one hardware class pool their measured speeds
(``ramps.core.speed.SpeedClass``): identical robots whose own figures differ
by measurement noise go by one figure, a robot that really differs keeps its
own, and the figures teammates pool are always their own (never pooled ones).
Driven through the real core: nodes hear each other's load reports."""

from __future__ import annotations

import importlib.util
import random
import sys
from pathlib import Path

import msgspec
import pytest

from ramps.core.config import RampsConfig
from ramps.core.events import Note, PeerLost, Received
from ramps.core.messages import LoadReport, decode, encode
from ramps.core.node import Node
from ramps.core.speed import POOL_MAX, POOL_MIN, SpeedClass, SpeedMeasured

CFG = RampsConfig()
FRACTION = 0.08  # 4 cores on 0.32 host cores: the testbed's robots
CPU = "Intel(R) Xeon(R) Processor"


def _node(name: str, speed: float, klass: str = CPU, policy: str = "ramps") -> Node:
    return Node(name, cores=4, speed=speed, policy=policy, config=CFG, rng=random.Random(1),
                core_fraction=FRACTION, speed_class=klass)


def _report(node: Node, *, periodic: bool = False) -> LoadReport:
    """``node``'s report of the instant (its nodes' ``load/<robot>/now`` key), or its periodic one,
    as teammates get it: over the wire."""
    msg = node.make_report(cpu_busy=0.0, runnable=0.0, ramps_avg=0.0, window=1.0) if periodic \
        else node.current_report(with_class=True)
    return decode(encode(node.robot, msg)).msg


def _exchange(nodes: list[Node], now: float = 10.0) -> None:
    """Every node hears every other's reports of the instant and periodic ones
    (twice: a node that changed its figure reports it again)."""
    for periodic in (False, True, False):
        reports = [_report(n, periodic=periodic) for n in nodes]
        for n in nodes:
            for r in reports:
                if r.robot != n.robot:
                    n.handle(Received(sender=r.robot, msg=r), now)


def test_the_median_of_the_class_within_the_noise_and_the_own_figure_beyond_it():
    c = SpeedClass(CPU)
    assert c.heard("a", CPU, 0.45) and c.heard("b", CPU, 0.47) and not c.heard("b", CPU, 0.47)
    assert not c.heard("x", "another CPU", 0.9) and "x" not in c.rates
    assert c.rate(0.46, 0.01) == (0.46, 3)  # the median of 0.45, 0.46, 0.47
    assert c.rate(0.44, 0.0) == (0.45, 3)  # within POOL_MIN whatever the error
    # 20% off: noise for a figure known to 10% (3 x 0.1 > 0.2), a different machine for one known to 1%
    assert c.rate(0.56, 0.1) == (0.47, 3)
    assert c.rate(0.56, 0.01) == (0.56, 1)
    assert c.rate(0.9, 0.5) == (0.9, 1)  # beyond POOL_MAX, whatever the error
    assert POOL_MIN < POOL_MAX
    assert SpeedClass("").rate(0.5, 0.0) == (0.5, 1)
    assert not SpeedClass("").heard("a", "", 0.4)
    assert c.forget("a") and not c.forget("a")


def test_identical_robots_that_measured_themselves_apart_go_by_one_figure():
    own = [0.0358, 0.0344, 0.0369, 0.0343, 0.0343]  # five robots at +20 s beside busy processes
    nodes = [_node(f"r{i}", s) for i, s in enumerate(own, 1)]
    _exchange(nodes)
    speeds = [n.speed for n in nodes]
    assert max(speeds) / min(speeds) <= 1.01 and speeds[0] == 0.0344  # own figures: 1.076 apart
    assert [n.executor.speed for n in nodes] == speeds == [n.view.speed for n in nodes]
    # what they pool is their own figure, per CPU second: never the pooled one
    for n, s in zip(nodes, own):
        report = _report(n)
        assert report.speed == pytest.approx(0.0344, abs=1e-4)
        assert report.cpu_rate == pytest.approx(s / FRACTION) and report.speed_class == CPU
    note = next(a for a in nodes[1].handle(SpeedMeasured(speed=0.0400), 40.0) if isinstance(a, Note))
    assert nodes[1].speed == 0.0358  # the median moved to r1's figure
    assert "median of 5 robots of its class" in note.detail


def test_a_robot_that_really_differs_keeps_its_own_figure_and_other_classes_stay_apart():
    nodes = [_node("r1", 0.0360), _node("r2", 0.0356), _node("r3", 0.0364),
             _node("slow", 0.0250),  # a throttled CPU: 30% off
             _node("other", 0.0340, klass="ARM Cortex-A72 / Raspberry Pi 4 Model B"),
             _node("told", 0.0345, klass="")]
    _exchange(nodes)
    by = {n.robot: n.speed for n in nodes}
    assert by["r1"] == by["r2"] == by["r3"] == 0.0360  # the slow robot left out of the median
    assert by["slow"] == 0.0250 and by["other"] == 0.0340 and by["told"] == 0.0345
    assert _report(nodes[-1]).cpu_rate is None and _report(nodes[-1]).speed_class is None


def test_a_robot_that_leaves_its_class_no_longer_counts():
    a, b, c = _node("a", 0.036), _node("b", 0.035), _node("c", 0.0345)
    _exchange([a, b, c])
    assert a.speed == pytest.approx(0.035)
    a.handle(PeerLost(robot="b"), 20.0)
    a.handle(PeerLost(robot="c"), 20.0)
    assert a.speed == pytest.approx(0.036) and not a.speed_class.rates


def test_a_policy_that_keeps_its_speed_pools_with_nobody():
    paper = _node("p", 0.030, policy="paper")
    others = [_node("a", 0.036), _node("b", 0.0355)]
    _exchange([paper, *others])
    assert paper.speed == 0.030 and _report(paper).cpu_rate is None


def test_reports_of_an_older_node_without_the_fields_still_decode_and_pool_nothing():
    old = msgspec.msgpack.encode({k: v for k, v in msgspec.structs.asdict(_report(_node("a", 0.036))).items()
                                  if k not in ("speed_class", "cpu_rate")})
    assert b"cpu_rate" not in old
    n = _node("b", 0.034)
    fields = msgspec.msgpack.decode(old)
    n.handle(Received(sender="a", msg=LoadReport(**fields)), 5.0)
    assert n.speed == 0.034 and not n.speed_class.rates


def test_only_reports_of_the_instant_carry_the_class_so_release_0_1_0_reads_the_periodic_ones():
    """0.1.0 decodes strictly and drops a report with a field it does not
    know; it hears only the periodic reports (the ``load/<robot>`` key)."""
    old = sys.modules.get("ramps_wire_0_1_0")  # as tests/test_wire_golden.py loads it
    if old is None:
        spec = importlib.util.spec_from_file_location("ramps_wire_0_1_0",
                                                      Path(__file__).parent / "golden" / "0.1.0" / "messages.py")
        assert spec is not None and spec.loader is not None
        old = sys.modules["ramps_wire_0_1_0"] = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(old)
    n = _node("a", 0.036)
    periodic = n.make_report(cpu_busy=0.0, runnable=0.0, ramps_avg=0.0, window=1.0)
    assert periodic.speed_class is None and old.decode(encode("a", periodic)).msg.speed == 0.036
    with pytest.raises(old.WireError, match="speed_class|cpu_rate"):
        old.decode(encode("a", n.current_report(with_class=True)))
    assert n.current_report().speed_class is None  # e.g. inside a 'busy' rejection, which 0.1.0 origins read


def test_a_new_own_figure_is_told_to_the_class_at_once():
    n = _node("a", 0.036)
    n.handle(SpeedMeasured(speed=0.036), 1.0)  # nothing moved: no report of the instant
    published = [a for a in n.handle(SpeedMeasured(speed=0.040), 3.0) + n.flush(3.0)
                 if type(a).__name__ == "PublishReport"]
    assert [a.report.cpu_rate for a in published] == [pytest.approx(0.040 / FRACTION)]


def test_a_node_that_hears_its_own_report_does_not_count_itself_twice():
    """A node subscribed to every robot's reports hears its own too: its
    class's median is of its teammates and itself, once."""
    a, b = _node("a", 0.030), _node("b", 0.036)
    a.handle(Received(sender="a", msg=_report(a)), 1.0)
    assert not a.speed_class.rates
    _exchange([a, b])
    assert a.speed_class.rates.keys() == {"b"} and a.speed == b.speed == pytest.approx(0.033)
