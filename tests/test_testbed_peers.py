"""``ramps testbed experiment peers`` (ramps.lab.peers and its parts): ramps beside round
robin, Ray and Dask on the same emulated robots. The pure parts (scenarios, the
ideal, distributions, the crash's victim, the report) run anywhere; one small
real run of ramps and round robin needs root and cgroups (skipped otherwise).
Ray and Dask are the ``peers`` extra, which ``make test`` does not install:
their real run is for ``ramps testbed experiment peers`` itself."""

from __future__ import annotations

import importlib.util
import json

import msgspec
import pytest
from typer.testing import CliRunner

from test_testbed import REASON, others_leftovers

from ramps.cli import app
from ramps.experiments.metrics import Machine, model_makespan
from ramps.lab.peers import ENGINES, run_peers
from ramps.lab.peers_engines import ClusterEngine, _running
from ramps.lab.peers_scenarios import (
    SCENARIOS, SPACING, EngineRun, PeersReport, ScenarioResult, Setup, distribution, format_report, ideal, medians, releases,
    victim,
)

runner = CliRunner()


def test_the_issue_scenarios_are_there():
    assert list(SCENARIOS) == ["idle", "busy-1", "busy-2", "busy-4", "origins", "crash"]
    assert [SCENARIOS[s].loaded for s in ("busy-1", "busy-2", "busy-4")] == [("r5",), ("r4", "r5"),
                                                                              ("r2", "r3", "r4", "r5")]
    assert SCENARIOS["origins"].origins == ("r1", "r2") and SCENARIOS["origins"].per_origin() == 15
    assert SCENARIOS["crash"].crash_at == 10.0 and SCENARIOS["crash"].programs == 15
    assert all(s.robots == 5 for s in SCENARIOS.values())
    assert SCENARIOS["idle"].with_programs(10).programs == 10 and SCENARIOS["idle"].with_programs(None).programs == 30
    assert set(ENGINES) == {"ramps", "round-robin", "ray", "dask", "ramps-nice0"}


def test_releases_follow_the_origins_submitting_together():
    sc = SCENARIOS["origins"].with_programs(4)
    assert releases(sc) == pytest.approx([0.0, 0.0, SPACING, SPACING])


def test_distribution_counts_where_programs_completed():
    assert distribution(["r1", "r3", None, "r3", "r9"], ["r1", "r2", "r3"]) == [1, 0, 2]


def test_the_ideal_of_idle_robots_spreads_evenly():
    span, dist = ideal(SCENARIOS["idle"], cores=4, speed=0.05, work=1.5, time_limit=1.0)
    assert dist == [6, 6, 6, 6, 6]
    # six programs on four cores, all released within 1.5 s: processor sharing ends them together
    assert model_makespan([6], [Machine(4, 0.05)], 1.5) <= span <= model_makespan([6], [Machine(4, 0.05)], 1.5) + 1.5


def test_the_ideal_keeps_nice_workers_off_busy_robots_and_leaves_out_the_crashed_one():
    _, dist = ideal(SCENARIOS["busy-2"], cores=4, speed=0.05, work=1.5, time_limit=1.0)
    assert dist[3:] == [0, 0] and sum(dist) == 30  # beside 8 busy processes a nice-10 program gets a tenth
    # at nice 0 a busy robot is worth a little: a program there gets 4/9 of a core
    _, dist0 = ideal(SCENARIOS["busy-4"].with_programs(60), cores=4, speed=0.05, work=1.5, worker_nice=0,
                     time_limit=1.0)
    assert sum(dist0[1:]) > 0
    span, dist = ideal(SCENARIOS["crash"], cores=4, speed=0.05, work=1.5, without=["r5"], time_limit=1.0)
    assert dist[4] == 0 and sum(dist) == 15
    assert span == pytest.approx(1.5 / 0.05, rel=0.05)  # 15 programs on 16 cores: one round


def test_the_crash_hits_the_busiest_robot_that_is_not_an_origin():
    assert victim({"r1": 4, "r2": 2, "r4": 3, "r5": 3}, ["r1"]) == "r5"
    assert victim({"r1": 4, "r2": 2}, ["r1", "r2"]) is None
    assert victim({}, ["r1"]) is None


def test_running_programs_are_read_from_the_marks(tmp_path):
    for name in ("start-r1_0_r2_11", "start-r1_1_r2_12", "end-r1_1_r2_12", "start-r2_0_r5_13"):
        (tmp_path / name).touch()
    assert _running(tmp_path) == {"r2": 1, "r5": 1}
    assert _running(tmp_path / "missing") == {}


def test_a_missing_engine_says_which_extra_to_install():
    assert ClusterEngine("nothing", "no_such_module_for_ramps").missing().startswith("no_such_module_for_ramps is not installed: pip install -e '.[peers]'")
    assert ENGINES["ramps"]().missing() is None


def test_the_report_prints_every_engine_and_reads_back_from_json():
    sc = SCENARIOS["crash"]
    runs = [EngineRun(engine="ramps", makespan=52.7, distribution=[4, 3, 4, 4, 0], completed=15, crashed="r5",
                      crashed_running=3, speed=0.05, ideal=45.0, ratio=1.171),
            EngineRun(engine="round-robin", makespan=40.0, distribution=[3, 3, 3, 3, 0], completed=12, lost=3,
                      speed=0.05, ideal=45.0, ratio=0.889),
            EngineRun(engine="ray", error="skipped: ray is not installed: pip install -e '.[peers]'")]
    rep = PeersReport(cores=4, quota=0.32, work=1.5, worker_nice=10,
                      scenarios=[ScenarioResult(scenario=sc, ideal=45.0, ideal_distribution=[4, 4, 4, 3, 0],
                                                sim=None, runs=runs)])
    text = format_report(rep)
    assert "ideal 45.0 s (4-4-4-3-0)" in text
    assert "52.7 s" in text and "4-3-4-4-0" in text and "crashed r5 with 3 running" in text
    assert "skipped: ray is not installed" in text
    assert [line.split()[5] for line in text.splitlines() if line.strip().startswith("round-robin")] == ["3"]
    back = msgspec.json.decode(msgspec.json.encode(rep), type=PeersReport)
    assert back == rep and back.scenarios[0].scenario.crash_at == 10.0


def test_rounds_in_turns_compare_each_engines_median_and_an_engine_that_lost_programs_has_none():
    sc = SCENARIOS["idle"]

    def run(engine: str, span: float, rnd: int, **kw) -> EngineRun:
        return EngineRun(engine=engine, makespan=span, completed=15, speed=0.04, ideal=40.0,
                         ratio=round(span / 40.0, 3), round=rnd, **kw)
    runs = [run("ramps", 48.9, 1), run("dask", 45.5, 1), run("round-robin", 47.0, 1, lost=1),
            run("ramps", 44.0, 2), run("dask", 46.0, 2), run("round-robin", 44.0, 2),
            run("ramps", 45.2, 3), run("dask", 47.0, 3), run("round-robin", 45.0, 3)]
    assert medians(runs) == {"ramps": (45.2, 1.13, 3), "dask": (46.0, 1.15, 3)}
    rep = PeersReport(cores=4, quota=0.32, work=1.5, worker_nice=0, repeats=3,
                      scenarios=[ScenarioResult(scenario=sc, ideal=44.0, ideal_distribution=[4, 4, 4, 2, 1],
                                                sim=None, runs=runs)])
    text = format_report(rep)
    assert "medians of rounds in turns: ramps 45.2 s (ratio 1.13), dask 46.0 s (ratio 1.15)" in text
    assert "ramps / the best other engine: 0.983" in text


def test_the_command_rejects_unknown_scenarios_and_engines():
    for args in (["-s", "nope"], ["-e", "spark"]):
        res = runner.invoke(app, ["testbed", "experiment", "peers", *args])
        assert res.exit_code == 2 and "choose from" in res.output


@pytest.mark.skipif(importlib.util.find_spec("ray") is not None and importlib.util.find_spec("distributed") is not None,
                    reason="the peers extra is installed")
def test_without_the_extra_ray_and_dask_are_skipped_and_say_why():
    rep = run_peers([], ["ray", "dask"])
    assert rep.scenarios == []
    assert ENGINES["ray"]().missing() or ENGINES["dask"]().missing()


@pytest.mark.slow  # not serial: it checks what ran where and that nothing was lost, no time or CPU share
@pytest.mark.skipif(REASON is not None, reason=REASON or "")
def test_ramps_and_round_robin_run_a_crash_end_to_end(tmp_path):
    """Two robots, eight short programs from r1 (more than its four cores), r2 crashed at 1.5 s
    while it runs some: ramps runs them again, every figure is filled in, the traces are kept."""
    sc = msgspec.structs.replace(SCENARIOS["crash"], robots=2, programs=8, crash_at=1.5)
    rep = run_peers([sc], ["ramps", "round-robin"], Setup(work=0.15, timeout=60.0, keep_logs=str(tmp_path)))
    for engine in ("ramps", "round-robin"):
        delivered = [line for line in (tmp_path / f"crash-{engine}" / "r1.trace.jsonl").read_text().splitlines()
                     if '"delivered"' in line]
        assert len(delivered) == 8
    (s,) = rep.scenarios
    assert [r.engine for r in s.runs] == ["ramps", "round-robin"]
    assert s.ideal and s.ideal_distribution == [8, 0]  # r2 left out: it crashes
    for r in s.runs:
        assert r.error is None, r.error
        assert r.speed > 0 and r.ideal and r.makespan and r.makespan > 1.5
        assert sum(r.distribution) == r.completed
        if r.crashed is not None:  # it had programs at 2 s: ramps runs them again
            assert r.crashed == "r2" and r.crashed_running >= 1
    assert s.runs[1].crashed == "r2"  # round robin had programs there
    ramps = s.runs[0]
    assert ramps.completed == 8 and ramps.lost == 0
    json.loads(msgspec.json.encode(rep))
    assert others_leftovers() == []


def test_dasks_orphaned_semaphores_are_removed_not_older_ones(tmp_path):
    import os
    import time

    from ramps.lab.peers_engines import _orphan_semaphores

    old, new, other = tmp_path / "sem.mp-old", tmp_path / "sem.mp-new", tmp_path / "zenoh.shm"
    for p in (old, new, other):
        p.touch()
    os.utime(old, (time.time() - 600, time.time() - 600))
    assert _orphan_semaphores(time.time() - 60, tmp_path) == 1
    assert not new.exists() and old.exists() and other.exists()


def test_a_burst_whose_time_ran_out_has_no_makespan_and_says_how_many_were_not_done():
    from ramps.lab.peers_engines import _Burst

    sc = SCENARIOS["busy-1"].with_programs(5)
    burst = _Burst(sc)
    burst.t0 = 100.0
    burst.hosts = ["r1", "r2", "r3", None, None]  # r5's two programs still running at the deadline
    burst.ends = [130.0, 131.0, 140.0]
    burst.unfinished = 2
    run = burst.result("ray")
    # the last completion (40 s) is not the burst's makespan: two programs never ended
    assert run.makespan is None and run.completed == 3 and run.unfinished == 2 and run.lost == 0
    rep = PeersReport(cores=4, quota=0.32, work=1.5, worker_nice=0,
                      scenarios=[ScenarioResult(scenario=sc, ideal=45.0, ideal_distribution=[1, 1, 1, 2, 0],
                                                sim=None, runs=[run])])
    assert "2 not done when the time was up" in format_report(rep)
    burst.unfinished = 0
    burst.hosts = ["r1", "r2", "r3", "r4", "r4"]
    burst.ends += [145.0, 150.0]
    assert burst.result("ray").makespan == 50.0


def test_the_busy_robots_own_cpu_is_read_from_their_load_processes():
    import os
    from types import SimpleNamespace

    from ramps.runtime.measure import proc_cpu
    from ramps.lab.peers_engines import _Burst, own_cpu

    me = os.getpid()
    tb = SimpleNamespace(robots={"r4": {"load_pids": [[me, 0]]}, "r5": {"load_pids": [[me, 0], [2 ** 22 + 7, 0]]}})
    assert own_cpu(tb, SCENARIOS["idle"]) is None  # nothing busy
    before = proc_cpu(me)[0]
    got = own_cpu(tb, SCENARIOS["busy-2"])  # this process twice; a process gone counts nothing
    assert 2 * before <= got <= 2 * proc_cpu(me)[0]
    burst = _Burst(SCENARIOS["busy-2"])
    burst.start(tb, 0.0)  # a burst that began long ago (monotonic 0): a small share of a core
    burst.stop(tb)
    assert burst.result("ramps").own_cpu is not None and burst.result("ramps").own_cpu >= 0


def test_rounds_run_every_engine_in_turns_each_round_starting_with_the_next(monkeypatch):
    import ramps.lab.experiments as experiments
    import ramps.lab.peers as peers

    order: list[tuple[str, int]] = []

    class Fake:
        def __init__(self, name: str) -> None:
            self.name = name

        def missing(self):
            return None

        def run(self, sc, setup, log):
            order.append((self.name, len(order)))
            return EngineRun(engine=self.name, makespan=40.0 + len(order), distribution=[3] * 5, completed=15)

    monkeypatch.setattr(peers, "ENGINES", {n: (lambda n=n: Fake(n)) for n in ("a", "b", "c")})
    monkeypatch.setattr(experiments, "identical_speed", lambda *a, **k: 0.04)
    monkeypatch.setattr(peers, "ideal", lambda sc, **k: (37.5, [3] * 5))
    monkeypatch.setattr(peers, "simulated", lambda sc, **k: None)
    rep = peers.run_peers([SCENARIOS["idle"]], ["a", "b", "c"], repeats=3)
    assert [name for name, _ in order] == ["a", "b", "c", "b", "c", "a", "c", "a", "b"]
    runs = rep.scenarios[0].runs
    assert [(r.engine, r.round) for r in runs][:4] == [("a", 1), ("b", 1), ("c", 1), ("b", 2)]
    assert medians(runs)["a"] == (46.0, pytest.approx(46.0 / 37.5, abs=1e-3), 3)
