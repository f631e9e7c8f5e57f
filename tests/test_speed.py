"""Robots' speeds re-measured while idle and corrected from results of the
same program on other robots (ramps.core.speed), in the core and the simulator."""

from __future__ import annotations

import random
from collections import Counter

import msgspec
import pytest

from ramps.core.config import RampsConfig
from ramps.core.events import Note, Received, Submit
from ramps.core.messages import ProgramResult
from ramps.core.node import Node
from ramps.core.speed import (REMEASURE_EARLY, REMEASURE_EARLY_COUNT, REMEASURE_PERIOD, HostSpeeds, SpeedEstimate,
                              SpeedMeasured, next_remeasure)
from ramps.sim.engine import simulate
from ramps.sim.scenario_file import scenario_from_dict
from ramps.testing import FakeTeam

CFG = RampsConfig()


def test_a_re_measurement_that_moved_replaces_the_estimate():
    """The driver's figure is already robust (the mean of its measurements,
    each of the fastest pieces it timed): the core takes it when it moved by more than 1%, up or
    down (a throttled CPU), and ignores nonsense."""
    est = SpeedEstimate(0.7, CFG)
    assert not est.measured(0.705)
    assert not est.measured(float("nan")) and not est.measured(0.0) and not est.measured(-1.0)
    assert est.measured(1.0) and est.value == 1.0
    assert est.measured(0.9) and est.value == 0.9


def test_speed_samples_average_the_cpus_and_outweigh_an_odd_measurement():
    from ramps.runtime.speed_probe import SpeedSamples

    s = SpeedSamples()
    assert s.rate() == 0.0
    # one CPU ran at 0.40 (a busy neighbour on its physical core), the other at 0.58;
    # pieces the scheduler cut (0.1, 0.2, 0.3) only get slower: the fastest quarter
    # of each CPU's pieces is its rate, however many were cut
    s.add({0: [0.40, 0.1, 0.2, 0.40, 0.3, 0.1, 0.2, 0.1], 1: [0.58, 0.58, 0.3, 0.2]})
    assert s.rate() == pytest.approx(0.49)
    assert s.speed(quota=0.32, cores=4) == pytest.approx(0.49 * 0.08, abs=1e-4)
    # the same CPUs with no piece cut: the same figure (a median said 0.15 and 0.44 above)
    s2 = SpeedSamples()
    s2.add({0: [0.40] * 8, 1: [0.58] * 4})
    assert s2.rate() == pytest.approx(s.rate())
    # the node's figure is the mean of its measurements, the fastest and the slowest
    # left out once there are five: a measurement taken while the neighbours' start-up
    # kept the machine busy counts for little, then nothing
    s.add({0: [0.30, 0.30], 1: [0.30, 0.30]})
    assert s.rate() == pytest.approx((0.49 + 0.30) / 2)
    for _ in range(3):
        s.add({0: [0.50, 0.50], 1: [0.48, 0.48]})
    assert s.rate() == pytest.approx(0.49)  # 0.30 and one 0.49 dropped, 0.49 0.49 0.49 left
    assert s.latest == pytest.approx(0.49)
    s.add({-1: [float("nan"), -1.0]})  # nothing measurable: no figure
    assert s.rate() == pytest.approx(0.49)
    assert s.latest == 0.0  # not the measurement before it


def test_the_boot_measurement_counts_only_until_the_grid_outvotes_it():
    from ramps.runtime.speed_probe import GRID_QUORUM, SpeedSamples

    s = SpeedSamples()
    # the node booted half a second after its teammates, on another phase of the vCPUs
    s.add({0: [0.30, 0.30, 0.30]}, boot=True)
    assert s.rate() == pytest.approx(0.30)
    for _ in range(GRID_QUORUM - 1):
        s.add({0: [0.50, 0.50, 0.50]})
        assert s.rate() < 0.50  # the boot figure still counts
    s.add({0: [0.50, 0.50, 0.50]})
    # the grid's measurements, taken at one moment by every robot: the boot figure no longer counts
    assert s.rate() == pytest.approx(0.50)
    for _ in range(3):
        s.add({0: [0.44, 0.44]})
    # the grid's 0.50 0.44 0.44 0.44 (and 0.50s before, if the quorum is larger), never the boot's 0.30
    assert 0.44 < s.rate() < 0.50


def test_runs_are_compared_only_with_runs_elsewhere_of_their_own_time():
    # a and b ran the program while the whole team ran at 0.7 of its speed (say, a host
    # shared with other work): 0.43 units a call where the team's CPU does it in 0.3 now
    speeds = HostSpeeds(CFG)
    speeds.on_result("burn", "a", 0.43, started=0.0, now=8.0)
    speeds.on_result("burn", "b", 0.43, started=0.0, now=8.0)
    # h's runs came after theirs ended: against them it would look 1.43x faster than it says
    assert not speeds.on_result("burn", "h", 0.30, started=10.0, now=16.0)
    assert not speeds.on_result("burn", "h", 0.30, started=10.0, now=16.0)
    assert "h" not in speeds.factor
    # next to a run of the same minute on a, it is compared, and a host slower than the
    # others of its time is slow
    speeds.on_result("burn", "a", 0.30, started=20.0, now=26.0)
    assert not speeds.on_result("burn", "h", 0.45, started=21.0, now=28.0)
    assert speeds.on_result("burn", "h", 0.45, started=21.5, now=28.5)
    assert speeds.factor["h"] == pytest.approx(0.30 / 0.45)


def test_a_host_slower_than_it_says_on_the_same_program_gets_a_factor():
    speeds = HostSpeeds(CFG)
    assert not speeds.on_result("plan", "a", 53.0)  # nothing to compare with yet
    assert not speeds.on_result("plan", "b", 53.0)  # the same as a: nothing to correct
    # h believes itself 1.5x faster than it is: it counts 1.5x the work;
    # one figure alone moves nothing, the second does
    assert not speeds.on_result("plan", "h", 79.5)
    assert speeds.on_result("plan", "h", 79.5)
    assert speeds.factor["h"] == pytest.approx(53.0 / 79.5)
    # its corrected runs now agree with the others': no change
    assert not speeds.on_result("plan", "h", 79.5)
    # a host faster than it says, on another program
    speeds.on_result("map", "a", 10.0)
    assert not speeds.on_result("map", "f", 5.0)
    assert speeds.on_result("map", "f", 5.0)
    assert speeds.factor["f"] == pytest.approx(CFG.speed_max_correction)


def test_calls_of_different_declared_sizes_compare_per_declared_unit():
    speeds = HostSpeeds(CFG)
    # a ran a call declared 10 units that took 12; h ran calls declared 40
    # that took 48 each: the same speed, nothing to correct
    speeds.on_result("plan", "a", 12.0, declared=10.0)
    for _ in range(3):
        assert not speeds.on_result("plan", "h", 48.0, declared=40.0)
    assert speeds.factor == {}
    # s takes 1.5x per declared unit, twice: corrected
    assert not speeds.on_result("plan", "s", 27.0, declared=15.0)
    assert speeds.on_result("plan", "s", 27.0, declared=15.0)
    assert speeds.factor["s"] == pytest.approx(1.2 / 1.8)


def test_a_run_far_off_the_others_is_another_instance_not_another_speed():
    """The demo's case: a warm-up of route plans of 4 picks, then plans of 14
    under the same name and declaration: 4-8x the work, on identical robots."""
    speeds = HostSpeeds(CFG)
    for host, done in (("a", 0.21), ("b", 0.22), ("c", 0.20)):
        speeds.on_result("route_plan", host, done, declared=2.0)
    for host in "abc":
        assert not speeds.on_result("route_plan", host, 1.4, declared=2.0)
    assert speeds.factor == {}


def test_a_program_bigger_than_declared_everywhere_is_not_a_slow_team():
    speeds = HostSpeeds(CFG)
    for host in "abcab":
        assert not speeds.on_result("plan", host, 4 * 13.25)
    assert speeds.factor == {}


def test_one_odd_result_does_not_move_a_factor_and_nonsense_is_ignored():
    speeds = HostSpeeds(CFG)
    speeds.on_result("plan", "a", 53.0)
    for _ in range(4):
        speeds.on_result("plan", "h", 53.0)
    assert not speeds.on_result("plan", "h", 5.0)  # the median of h's last five holds
    for bad in (0.0, -1.0, float("nan"), float("inf")):
        assert not speeds.on_result("plan", "h", bad)
    assert speeds.factor.get("h", 1.0) == 1.0


def test_a_run_too_short_to_measure_says_nothing_of_its_host():
    """Warm-up calls of a few milliseconds measure their start-up, not the
    host: they neither set a reference nor move a factor."""
    speeds = HostSpeeds(CFG)
    speeds.on_result("plan", "a", 0.05)
    for _ in range(5):
        assert not speeds.on_result("plan", "h", 0.02)
    assert speeds.samples == 0 and speeds.factor == {}
    # long enough, the same comparison corrects h
    speeds.on_result("plan", "a", 5.0)
    assert [speeds.on_result("plan", "h", 3.0) for _ in range(2)] == [False, True]


def test_robots_re_measure_on_one_wall_clock_grid_often_at_first_then_settle():
    """Robots that booted 0.3 s apart measure again at the same moments."""
    a, b = 1000.2, 1000.5
    assert next_remeasure(a, 0) == next_remeasure(b, 0) == pytest.approx(1002.0)
    t, count = a, 0
    times = []
    while count < REMEASURE_EARLY_COUNT + 2:
        t = next_remeasure(t, count)
        times.append(t)
        count += 1
    gaps = [y - x for x, y in zip(times, times[1:])]
    assert all(g == pytest.approx(REMEASURE_EARLY) for g in gaps[:REMEASURE_EARLY_COUNT - 1])
    assert gaps[-1] == pytest.approx(REMEASURE_PERIOD) and times[-1] % REMEASURE_PERIOD == pytest.approx(0.0)
    assert all(next_remeasure(x, 0) >= x + 1.0 for x in (0.0, 2.0, 2.5, 2.99, 1e9 + 0.1))


def test_a_steady_speed_is_measured_less_often_on_the_same_grid():
    """Each settled re-measurement that did not move the speed doubles the
    period, at most REMEASURE_BACKOFF times; every longer period's moments
    are moments of the shorter ones, so robots at different stages of the
    back-off still measure at common moments."""
    from ramps.core.speed import REMEASURE_BACKOFF

    t, settled = 10_000.0, REMEASURE_EARLY_COUNT
    top = REMEASURE_PERIOD * 2 ** REMEASURE_BACKOFF
    for steady in range(REMEASURE_BACKOFF + 3):
        period = REMEASURE_PERIOD * 2 ** min(steady, REMEASURE_BACKOFF)
        nxt = next_remeasure(t, settled, steady)
        # the next moment of its own period's grid, which is on the settled grid too
        assert nxt % period == pytest.approx(0.0) and t + 1.0 <= nxt <= t + 1.0 + period
        t = nxt
    assert t % top == pytest.approx(0.0)  # no further apart than the cap: 480 s
    assert next_remeasure(t, settled, 0) - t == pytest.approx(REMEASURE_PERIOD)  # moved: back to the period
    assert next_remeasure(5.0, 3, steady=4) == next_remeasure(5.0, 3)  # boot's early moments never back off


def test_the_node_backs_off_only_while_its_measurements_agree(monkeypatch):
    """``RobotMeasure`` counts the re-measurements in a row that left its
    speed where it was, with the real ``SpeedSamples`` and ``speed_moved``
    (a measurement that moves the mean by more than 1% starts over)."""
    import ramps.runtime.node_robot as nr
    from ramps.runtime.settings import NodeSettings

    class StillClock:  # the moment is now: nothing to wait for
        def monotonic(self) -> float:
            return 0.0

        def time(self) -> float:
            return 0.0

        def sleep(self, seconds: float) -> None:
            pass

    rates = iter([1.0])

    def fake_measure(seconds, *, quota=None, cores=1, samples=None, apart=False, boot=False, stop=None):
        r = next(rates)
        samples.add({0: [r]}, boot=boot)
        return samples.speed(quota=quota, cores=cores)

    monkeypatch.setattr(nr, "measure_speed", fake_measure)
    rm = nr.RobotMeasure(NodeSettings(robot="r", team="t", cores=1), StillClock(), "r")
    rm.samples.add({0: [1.0]}, boot=True)
    rm._remeasure(0.0, lambda: True, lambda item: None)  # one of the boot's early moments: no back-off yet
    assert rm.steady == 0
    rates = iter([1.0, 1.0, 1.3, 1.3])
    rm.remeasures = REMEASURE_EARLY_COUNT + 1  # settled
    got = []
    for _ in range(4):
        rm._remeasure(0.0, lambda: True, got.append)
        got.append(rm.steady)
    steady = [x for x in got if isinstance(x, int)]
    assert steady == [1, 2, 0, 0]  # 1.0, 1.0 agree; 1.3 moves the mean twice over
    assert len([x for x in got if isinstance(x, tuple)]) == 4  # every figure still goes to the core


def test_speed_learning_off_keeps_every_measurement():
    off = msgspec.structs.replace(CFG, speed_learning=False)
    assert not SpeedEstimate(0.7, off).measured(1.0)
    speeds = HostSpeeds(off)
    speeds.on_result("plan", "a", 53.0)
    assert not speeds.on_result("plan", "h", 106.0)


def test_config_rejects_a_bound_below_one():
    with pytest.raises(ValueError, match="speed_max_correction"):
        RampsConfig(speed_max_correction=0.5)


def _result(node: Node, host: str, pid: str, work_done: float) -> list:
    """``node`` placed ``pid`` on ``host`` (accepted), which ends it counting ``work_done``."""
    return node.handle(Received(sender=host, msg=ProgramResult(program_id=pid, attempt=1, host=host, ok=True,
                                                                value=b"", work_done=work_done)), 10.0)


def test_an_origin_places_by_the_speed_results_showed(monkeypatch):
    team = FakeTeam({"o": (1, 1.0), "a": (4, 1.0), "h": (4, 1.5)})
    team.nodes["o"].executor.background = 10.0
    team.publish()
    o = team.nodes["o"]
    assert o.view.capacity("h") == (4, 1.5)
    # three programs ran: one on a, two on h, each 53 units of real work
    for pid, host, done in (("p1", "a", 53.0), ("p2", "h", 79.5), ("p3", "h", 79.5)):
        team.handle("o", Submit(program_id=pid, program="route_plan", work=53.0))
        ap = o.origin.programs[pid]
        ap.live[ap.attempt] = host  # as if placed there and accepted
        out = _result(o, host, pid, done)
    assert any(isinstance(a, Note) and a.what == "speed" and a.robot == "h" for a in out)
    assert o.view.capacity("h") == (4, pytest.approx(1.0))


def test_a_node_re_measured_while_idle_takes_the_faster_figure():
    node = Node("h", cores=4, speed=0.7, policy="ramps", config=CFG, rng=random.Random(1))
    out = node.handle(SpeedMeasured(speed=1.0), 30.0)
    assert any(isinstance(a, Note) and a.what == "speed" for a in out)
    assert node.speed == node.view.speed == node.executor.speed == 1.0
    assert node.make_report(cpu_busy=0, runnable=0, ramps_avg=0, window=1).speed == 1.0


def test_the_papers_policy_keeps_its_measured_speed():
    node = Node("h", cores=4, speed=0.7, policy="paper", config=CFG, rng=random.Random(1))
    node.handle(SpeedMeasured(speed=3.0), 200.0)
    assert node.speed == 0.7 and node.host_speeds is None


def _team(measured: dict[str, float], *, origins: dict[str, int], learning: bool, faults=()) -> dict:
    """Five identical robots of 4 cores; some measured their speed wrong at
    boot. Four waves of programs 100 s apart from each origin."""
    robots = [{"name": f"r{i}", "cores": 4, "speed": 1.0,
               **({"measured_speed": measured[f"r{i}"]} if f"r{i}" in measured else {})} for i in range(1, 6)]
    programs = [{"program": "route_plan", "count": n, "work": 53, "origin": o, "at": 100.0 * w, "spacing": 0.05}
                for w in range(4) for o, n in origins.items()]
    return {"name": "speeds", "seed": 1, "policy": "ramps", "robots": robots, "programs": programs,
            "faults": list(faults), "config": {"speed_learning": learning}}


def _waves(result) -> list[Counter]:
    waves: dict[int, Counter] = {}
    for p in result.programs:
        waves.setdefault(int(p.submitted_at // 100), Counter())[p.host] += 1
    return [waves[w] for w in sorted(waves)]


@pytest.mark.parametrize("seed", [1, 2])
def test_robots_that_measured_themselves_slow_get_their_share_after_re_measuring(seed):
    """The issue's case: two of five identical robots measured 0.7 of the
    others at boot, and 15 programs went 5-5-5 onto the other three."""
    data = _team({"r1": 0.7, "r2": 0.7}, origins={"r1": 15}, learning=True)
    before = simulate(scenario_from_dict(_team({"r1": 0.7, "r2": 0.7}, origins={"r1": 15}, learning=False)),
                      seed=seed)
    after = simulate(scenario_from_dict(data), seed=seed)
    assert [max(w.values()) for w in _waves(before)] == [5, 5, 5, 5]
    assert before.makespan > 366
    # from the first re-measurement (30 s after boot) on, every program gets a whole core
    assert all(max(w.values()) <= 4 for w in _waves(after)[1:])
    assert after.makespan < 300 + 53 * 1.02
    assert after.lost == after.duplicated == 0


@pytest.mark.parametrize("seed", [1, 2])
def test_a_robot_that_measured_itself_fast_is_corrected_by_its_results(seed):
    """r3 believes itself 1.5x faster than its four identical teammates:
    it takes five or six programs of twenty where four each is the optimum,
    until its results, next to the same program's elsewhere, show its real
    speed."""
    over = {"r3": 1.5}
    before = simulate(scenario_from_dict(_team(over, origins={"r1": 20}, learning=False)), seed=seed)
    after = simulate(scenario_from_dict(_team(over, origins={"r1": 20}, learning=True)), seed=seed)
    assert all(w["r3"] in (5, 6) for w in _waves(before))
    assert [dict(w) for w in _waves(after)[1:]] == [{f"r{i}": 4 for i in range(1, 6)}] * 3
    assert after.makespan < 300 + 53 * 1.02 < before.makespan
    assert after.lost == after.duplicated == 0


def test_robots_all_wrong_together_are_set_right_by_measuring_again():
    """Three of five believe themselves 1.5x faster and every run of the first
    wave goes to them: the results have nothing to compare with, but their
    next measurements outvote the boot figure, and the next waves spread."""
    over = {"r3": 1.5, "r4": 1.5, "r5": 1.5}
    result = simulate(scenario_from_dict(_team(over, origins={"r1": 15}, learning=True)), seed=1)
    waves = _waves(result)
    assert max(waves[0].values()) == 5
    assert all(dict(w) == {f"r{i}": 3 for i in range(1, 6)} for w in waves[1:])
    assert result.lost == result.duplicated == 0


def test_a_host_that_measured_itself_again_starts_its_correction_over():
    """A factor learned against a boot figure 1.5x too fast must not scale the
    host's re-measured true speed down too."""
    speeds = HostSpeeds(CFG)
    assert not speeds.on_reported_speed("h", 1.5)
    speeds.on_result("plan", "a", 53.0)
    speeds.on_result("plan", "h", 79.5)
    assert speeds.on_result("plan", "h", 79.5) and speeds.factor["h"] == pytest.approx(2 / 3)
    assert not speeds.on_reported_speed("h", 1.505)  # within 1%: the same measurement
    assert speeds.on_reported_speed("h", 1.0) and "h" not in speeds.factor


def test_several_origins_and_a_crash_with_mis_measured_robots():
    """Two origins submitting at once, r5 crashing in the second wave and
    coming back: nothing lost or run twice, and the last wave still gets a
    core per program."""
    data = _team({"r2": 0.7, "r4": 1.5}, origins={"r1": 10, "r2": 10}, learning=True,
                 faults=[{"at": 120.0, "robot": "r5", "kind": "crash"},
                         {"at": 150.0, "robot": "r5", "kind": "recover"}])
    for seed in (1, 2, 3):
        result = simulate(scenario_from_dict(data), seed=seed)
        assert result.lost == result.duplicated == 0 and result.completed == 80
        assert all(max(w.values()) <= 4 for w in _waves(result)[2:])
        assert result.makespan < 300 + 53 * 1.05


def _host_result(core_fraction: float, **finished) -> ProgramResult:
    """A host of 4 cores at speed 0.04 (each core 0.08 of a CPU under its
    quota, or whole) runs a program declared 1 unit for 10 s and reports it."""
    from ramps.core.events import ProgramFinished
    from ramps.core.executor import Executor
    from ramps.core.messages import OffloadRequest

    ex = Executor("h", config=CFG, cores=4, speed=0.04, core_fraction=core_fraction)
    out: list = []
    ex.on_offload(OffloadRequest(program_id="p", attempt=1, origin="o", host="h", program="burn", work=1.0), 0.0, out)
    out.clear()
    ex.on_finished(ProgramFinished(program_id="p", attempt=1, ok=True, **finished), 10.0, out)
    return next(a.msg for a in out if isinstance(getattr(a, "msg", None), ProgramResult))


def test_a_host_counts_a_programs_work_from_the_cpu_seconds_it_used():
    # 0.4 units by processor sharing (10 s at 0.04); 1.0 CPU s at 0.5 units per CPU s is 0.5 units
    assert _host_result(0.08).work_done == pytest.approx(0.4)
    assert _host_result(0.08, cpu_s=1.0).work_done == pytest.approx(0.5)
    assert _host_result(1.0, cpu_s=1.0).work_done == pytest.approx(0.04)
    # a program that slept through its 10 s did next to no work, whatever its share
    assert _host_result(0.08, cpu_s=0.001).work_done == pytest.approx(0.0005)
    assert _host_result(0.08, cpu_s=float("nan")).work_done == pytest.approx(0.4)


def test_the_speeds_experiment_reads_each_re_measurement_from_a_trace(tmp_path):
    import json

    from ramps.lab.speeds import measurements

    lines = [{"t": 1.0, "what": "placed", "detail": "expected 2.00 s"},
             {"t": 2.0, "what": "speed_measured", "detail": "0.04123 at 1800000003.0, node figure 0.04101"}]
    (tmp_path / "r1.trace.jsonl").write_text("".join(json.dumps(x) + "\n" for x in lines))
    assert measurements(tmp_path, ["r1", "r2"]) == {"r1": [[1800000003.0, 0.04123, 0.04101]], "r2": []}


def test_the_speeds_experiment_tells_each_robots_own_figure_beside_the_pooled_one():
    from ramps.lab.speeds import SpeedsReport, SpeedStart, own_figures

    boot = {"r1": 0.040, "r2": 0.044}
    measured = {"r1": [[100.0, 0.041, 0.041], [103.0, 0.039, 0.040]], "r2": [[103.0, 0.045, 0.0445]]}
    assert own_figures(boot, measured, 101.0) == {"r1": 0.041, "r2": 0.044}
    assert own_figures(boot, measured, 110.0) == {"r1": 0.040, "r2": 0.0445}
    start = SpeedStart(boot=boot, reported={"20.0": {"r1": 0.042, "r2": 0.042}},
                       own={"20.0": own_figures(boot, measured, 110.0)})
    table = SpeedsReport(robots=2, cores=4, quota=0.32, loaded=8, starts=[start]).table()
    assert "1 | 0.0400 0.0440 | 1.100 | inf | inf | 1.000 | 1.112" in table
    assert table.endswith("1/1 at +20 s (0/1 by their own figures, before pooling)")
