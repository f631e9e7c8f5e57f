"""The ramps command as a user runs it: real subprocess-free CLI invocations."""

from __future__ import annotations

import json

import pytest
from typer.testing import CliRunner

from ramps.cli import app

runner = CliRunner()


def invoke(*args: str):
    return runner.invoke(app, list(args), catch_exceptions=False)


def test_help_lists_the_commands():
    res = invoke("--help")
    assert res.exit_code == 0
    for word in ("sim", "bench", "version"):
        assert word in res.output


@pytest.mark.slow
def test_sim_paper_json_carries_classification_per_distribution():
    res = invoke("sim", "paper", "--experiment", "unloaded", "--runs", "1", "--json")
    assert res.exit_code == 0, res.output
    data = json.loads(res.stdout)
    assert data["experiment"] == "unloaded" and data["policy"] == "ramps"
    runs = [r for c in data["configs"] for r in c["runs"]]
    assert len(runs) == 24  # 4 team sizes x 6 program counts x 1 run
    assert {r["classification"] for r in runs} <= {"optimal", "near_optimal", "non_optimal"}
    for r in runs:
        assert r["ratio_to_round_robin"] == pytest.approx(r["makespan"] / r["round_robin_makespan"])
        assert sum(r["distribution"]) in (5, 10, 15, 20, 25, 30)
    s = data["summary"]
    assert s["optimal"] + s["near_optimal"] + s["non_optimal"] == 24


@pytest.mark.slow
def test_sim_paper_table_has_summary_line():
    res = invoke("sim", "paper", "--experiment", "loaded", "--runs", "1", "--policy", "paper")
    assert res.exit_code == 0
    assert "loaded / paper" in res.output and "optimal or near optimal" in res.output
    assert "optimum" in res.output


def test_sim_paper_rejects_unknown_policy_and_experiment():
    res = invoke("sim", "paper", "--policy", "fastest")
    assert res.exit_code == 2 and "unknown policy 'fastest'" in res.output
    res = invoke("sim", "paper", "--experiment", "huge")
    assert res.exit_code == 2 and "unknown experiment" in res.output


GOOD = """\
name: tiny
seed: 3
robots:
  - {name: a, cores: 2}
  - {name: b, cores: 2}
programs:
  - {origin: a, count: 6, work: 10}
faults:
  - {at: 3, robot: b, kind: crash}
"""


def test_sim_run_json(tmp_path):
    f = tmp_path / "tiny.yaml"
    f.write_text(GOOD)
    out = tmp_path / "res.json"
    res = invoke("sim", "run", str(f), "--json", "--out", str(out))
    assert res.exit_code == 0, res.output
    data = json.loads(res.stdout)
    assert data["completed"] == 6 and data["lost"] == 0 and data["duplicated"] == 0
    assert json.loads(out.read_text())["completed"] == 6
    # b crashed mid-run: whatever it had was restarted on a, which ran them all
    assert data["distribution"] == {"a": 6, "b": 0}


def test_sim_run_table_and_policy_override(tmp_path):
    f = tmp_path / "tiny.yaml"
    f.write_text(GOOD.replace("faults:\n  - {at: 3, robot: b, kind: crash}\n", ""))
    res = invoke("sim", "run", str(f), "--policy", "round_robin")
    assert res.exit_code == 0
    assert "policy round_robin" in res.output
    assert "completed 6" in res.output


@pytest.mark.parametrize(
    "text, expect",
    [
        (GOOD.replace("cores: 2}", "cores: two}", 1), "tiny.yaml:4: robots[0].cores"),
        (GOOD.replace("origin: a", "origin: z"), "unknown robot 'z'"),
        (GOOD.replace("kind: crash", "kind: explode"), "faults[0].kind"),
        ("robots: [\n", "tiny.yaml"),
        ("", "empty"),
    ],
)
def test_sim_run_rejects_bad_scenarios_without_traceback(tmp_path, text, expect):
    f = tmp_path / "tiny.yaml"
    f.write_text(text)
    res = invoke("sim", "run", str(f))
    assert res.exit_code == 2
    assert expect in res.output
    assert "Traceback" not in res.output


def test_sim_run_missing_file():
    res = invoke("sim", "run", "/nonexistent/scenario.yaml")
    assert res.exit_code == 2
    assert "Traceback" not in res.output


@pytest.mark.slow
def test_bench_sim_small_writes_json(tmp_path):
    out = tmp_path / "b.json"
    res = invoke("bench", "sim", "--runs", "1", "--robots", "20", "--programs", "100", "--origins", "2",
                 "--out", str(out))
    assert res.exit_code == 0, res.output
    data = json.loads(out.read_text())
    assert data["large"]["completed"] == 100 and data["large"]["lost"] == 0
    assert data["sweep"]["wall_seconds"] > 0


def test_testbed_experiment_saves_finished_experiments_as_it_goes_and_on_ctrl_c(tmp_path, monkeypatch):
    """A long `testbed experiment faults --mode all` keeps each finished
    experiment in --out, and Ctrl-C prints and saves what finished. The
    simulator's plan runner stands in for the testbed's (same plans, same
    FaultRun records); the second experiment is interrupted."""
    import ramps.experiments.faults as faults
    import ramps.lab.experiments as tbx

    calls = []

    def sim_runner(plan, *, seed=0, policy="ramps", **_testbed_options):
        calls.append(plan.name)
        if plan.mode == "simultaneous":
            partial = json.loads(out_file.read_text())  # saved before the next experiment started
            assert partial["partial"] is True and [e["mode"] for e in partial["experiments"]] == ["sequential"]
            raise KeyboardInterrupt
        return faults.run_plan(plan, seed=seed, policy=policy)

    out_file = tmp_path / "faults.json"
    monkeypatch.setattr(tbx, "run_plan", sim_runner)
    r = runner.invoke(app, ["testbed", "experiment", "faults", "--mode", "all", "--kind", "crash", "--gap", "20",
                            "--out", str(out_file)])
    assert r.exit_code == 130, r.output
    assert "interrupted: the 1 finished experiment(s) follow" in r.output
    saved = json.loads(out_file.read_text())
    assert saved["mode"] == "sequential" and saved["kind"] == "crash"
    assert saved["summary"]["completed"] == 15 * saved["summary"]["runs"]
    assert len(calls) == 2


def test_testbed_campaign_ctrl_c_reports_the_runs_that_finished(tmp_path, monkeypatch):
    """Ctrl-C during run 3 of a testbed campaign: the two finished runs are
    printed and saved with `interrupted`, exit 130. The simulator's campaign
    run stands in for a testbed run (same CampaignRun records)."""
    import random

    import ramps.experiments.campaign as sim_campaign
    import ramps.lab.campaign as tbx

    def sim_run(run_seed, *, policy="ramps", robots=4, duration=20.0, **_testbed_options):
        if run_seed % 1_000_000 == 2:
            raise KeyboardInterrupt
        sim = sim_campaign.run_one(run_seed, policy)
        faults = tbx.campaign_plan(random.Random(run_seed), [f"r{i}" for i in range(1, robots + 1)], duration)
        return tbx.CampaignRun(seed=run_seed, robots=sim.robots, programs=sim.programs, faults=faults,
                               completed=sim.completed, lost=sim.lost, duplicated=sim.duplicated,
                               not_rejoined=sim.not_rejoined, ok=sim.ok, seconds=0.1)

    monkeypatch.setattr(tbx, "run_campaign_once", sim_run)
    out_file = tmp_path / "campaign.json"
    r = runner.invoke(app, ["testbed", "campaign", "--runs", "5", "--seed", "4", "--out", str(out_file)])
    assert r.exit_code == 130, r.output
    assert "interrupted: the 2 run(s) that finished follow" in r.output
    saved = json.loads(out_file.read_text())
    assert saved["interrupted"] is True and saved["runs"] == 2
    assert [x["seed"] for x in saved["all_runs"]] == [4_000_000, 4_000_001]
    assert saved["programs"] == sum(x["programs"] for x in saved["all_runs"]) > 0
