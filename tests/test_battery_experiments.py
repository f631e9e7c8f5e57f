"""The battery family against its exact optimum (``ramps sim battery``) and
the energy curve (``ramps sim energy``): the optimum checked by brute force
on small instances, the family's invariants, the curve's direction."""

from __future__ import annotations

import itertools
import json
import math

import msgspec
import pytest
from typer.testing import CliRunner

from ramps.cli import app
from ramps.core.cost import NetworkEstimate
from ramps.experiments.battery import (FULL, MAX_PROGRAMS, full, generate, hosting_until, jobs_of, optimum,
                                       run_family)
from ramps.experiments.deadlines_optimum import shared_ends
from ramps.experiments.energy import run_curve
from ramps.sim.scenario import FaultSpec, ProgramSpec, RobotSpec, Scenario

runner = CliRunner()


def _brute_force(sc: Scenario) -> float:
    """The optimum by trying every placement (for a handful of programs)."""
    jobs, team = jobs_of(sc), sc.team()
    net = NetworkEstimate(latency=sc.network.latency, bandwidth=sc.network.bandwidth)
    until = hosting_until(sc)
    best = math.inf
    for hosts in itertools.product(range(len(team)), repeat=len(jobs)):
        worst = 0.0
        for r, robot in enumerate(team):
            mine = [k for k, h in enumerate(hosts) if h == r]
            if not mine:
                continue
            own = [jobs[k].origin == robot.name for k in mine]
            starts = [jobs[k].release + (0.0 if o else 2 * net.latency + jobs[k].payload / net.bandwidth)
                      for k, o in zip(mine, own)]
            ends = shared_ends(starts, [jobs[k].work for k in mine], robot.speed, robot.cores)
            if any(e > until[robot.name] + 1e-9 for e, o in zip(ends, own) if not o):
                worst = math.inf
                break
            worst = max([worst] + [e + (0.0 if o else net.latency + jobs[k].result / net.bandwidth)
                                   for e, o, k in zip(ends, own, mine)])
        best = min(best, worst)
    return best - min(j.release for j in jobs)


def _small(**kw) -> Scenario:
    robots = [RobotSpec(name="o", cores=1, speed=1.0, battery=0.9), RobotSpec(name="low", cores=4, speed=4.0,
                                                                               battery=kw.pop("low", 0.1)),
              RobotSpec(name="b", cores=2, speed=1.0, battery=0.9)]
    return Scenario(name="small", robots=robots, faults=kw.pop("faults", []),
                    programs=[ProgramSpec(origin="o", count=3, work=12.0, spacing=0.5),
                              ProgramSpec(origin="low", count=1, work=20.0)])


@pytest.mark.parametrize("sc", [_small(), _small(low=0.9), _small(low=0.9, faults=[
    FaultSpec(at=4.0, robot="low", kind="battery", charge=0.1)]), _small(low=0.9, faults=[
    FaultSpec(at=2.0, robot="b", kind="crash")])], ids=["low", "full", "drop", "crash"])
def test_the_optimum_is_the_best_placement_that_keeps_low_robots_to_their_own(sc: Scenario) -> None:
    assert optimum(sc) == pytest.approx(_brute_force(sc))


def test_a_low_robot_hosts_only_its_own_in_the_optimum() -> None:
    low, charged = optimum(_small()), optimum(_small(low=0.9))
    assert low > charged  # the fast robot is kept out for o's programs
    assert hosting_until(_small()) == {"o": math.inf, "low": -math.inf, "b": math.inf}


def test_the_family_is_small_enough_for_the_exact_optimum_and_reproducible() -> None:
    for i in range(30):
        sc = generate(i)
        assert sc == generate(i) and 3 <= len(sc.robots) <= 5 and 4 <= len(jobs_of(sc)) <= MAX_PROGRAMS
        events = sc.name.split("-", 2)[2].split("+")
        assert set(events) <= {"low", "drop", "crash", "none"}
        origins = {p.origin for p in sc.programs}
        assert not [f for f in sc.faults if f.kind == "crash" and f.robot in origins]
        assert ("drop" in events) == any(f.kind == "battery" for f in sc.faults)
        assert all(r.battery == 1.0 for r in full(sc).robots) and not [f for f in full(sc).faults
                                                                       if f.kind == "battery"]


def test_a_few_scenarios_run_every_variant_and_lose_nothing() -> None:
    rep = run_family(4)
    assert len(rep.rows) == 4
    for row in rep.rows:
        assert set(row.ratio) == {"ramps", "ramps_without", "round_robin", FULL}
        assert not any(row.lost.values()) and not any(row.duplicated.values())
        assert row.violations["ramps"] <= row.violations["ramps_without"]
    assert rep.summary["ramps"]["violations"] < rep.summary["ramps_without"]["violations"]
    assert json.loads(msgspec.json.encode(rep))["summary"]["ramps"]["median"] > 0


def test_the_energy_curve_trades_makespan_for_joules() -> None:
    rep = run_curve((0.0, 0.5, 1.0), seeds=1, programs=4)
    first, middle, last, rr = rep.points
    assert (first.weight, last.weight, rr.weight, rr.policy) == (0.0, 1.0, None, "round_robin")
    assert first.makespan <= middle.makespan <= last.makespan
    assert first.energy >= middle.energy >= last.energy and last.energy < first.energy
    assert last.work_share["frugal"] > first.work_share["frugal"]
    assert not any(p.lost or p.duplicated for p in rep.points)


def test_ramps_sim_energy_prints_and_saves_the_curve(tmp_path) -> None:
    out = tmp_path / "curve.json"
    res = runner.invoke(app, ["sim", "energy", "--weights", "0,1", "--seeds", "1", "--programs", "2", "-o", str(out)],
                        env={"COLUMNS": "200"})
    assert res.exit_code == 0, res.output
    assert "makespan s" in res.output and "frugal" in res.output
    assert [p["weight"] for p in json.loads(out.read_text())["points"]] == [0.0, 1.0, None]
    bad = runner.invoke(app, ["sim", "energy", "--weights", "0,2"])
    assert bad.exit_code != 0 and "--weights" in bad.output
