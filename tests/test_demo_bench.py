"""The README's main job (``ramps demo``) and ``ramps bench dispatch``, small and real."""

from __future__ import annotations

import json
from pathlib import Path

import psutil

import pytest
from typer.testing import CliRunner

from ramps.bench.demo import route_calls, run_demo
from ramps.cli import app
from ramps.programs.route import ROUTE_SIZES, plan_route

pytestmark = pytest.mark.slow


@pytest.fixture
def teams(monkeypatch) -> list[str]:
    """The names of the teams this test starts (ramps.testing.LocalTeam), so
    the leftover check looks at this test's nodes and cgroups only: tests
    running beside it (pytest-xdist) start teams of their own."""
    from ramps.testing import local

    started: list[str] = []
    start = local.LocalTeam.start

    def recording(self, *args, **kwargs):
        started.append(self.team)
        return start(self, *args, **kwargs)

    monkeypatch.setattr(local.LocalTeam, "start", recording)
    return started


def leftovers(teams: list[str]) -> list[str]:
    """Node processes or cgroups of these teams still around after they closed."""
    assert teams, "the test started no team"
    found = []
    for p in psutil.process_iter(["cmdline"]):
        cmd = " ".join(p.info["cmdline"] or [])
        if "ramps.cli node" in cmd and any(f"--team {t} " in cmd + " " for t in teams):
            found.append(cmd)
    for root in (Path("/sys/fs/cgroup/cpu"), Path("/sys/fs/cgroup")):
        if root.is_dir():
            found += [str(d) for t in teams for d in root.glob(f"ramps-{t}-*")]
    return found


def test_route_calls_explore_distinct_starts_of_one_order():
    calls = route_calls(dict(ROUTE_SIZES["tiny"]), 6)
    starts = [tuple(c["start"]) for c in calls]
    assert len(set(starts)) == 6
    lengths = [plan_route(**c)["length"] for c in calls]
    assert all(n > 0 for n in lengths)


def test_demo_runs_three_placements_on_a_real_team(teams, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # `make demo`'s report path is relative; the nodes run elsewhere
    rep = run_demo(robots=3, programs=6, arguments=dict(ROUTE_SIZES["tiny"]), kill=None, report="demo.html")
    assert (tmp_path / "demo.html").is_file() and (tmp_path / "demo.trace.jsonl").stat().st_size > 0
    names = [p.name for p in rep.phases]
    assert names == ["ramps", "round robin", "single robot (r1)"]
    for ph in rep.phases:
        assert ph.completed == 6 and ph.failed == 0, ph
    assert rep.phases[1].distribution == {"r1": 2, "r2": 2, "r3": 2}  # round robin
    assert rep.phases[2].distribution == {"r1": 6}  # local only
    assert rep.mode.startswith(("emulated robots", "shared host"))
    assert leftovers(teams) == []


def test_demo_survives_a_killed_robot(teams):
    rep = run_demo(robots=3, programs=6, arguments=dict(ROUTE_SIZES["tiny"], picks=9), kill="r3", kill_at=0.0)
    ramps_phase = rep.phases[0]
    assert ramps_phase.completed == 6 and ramps_phase.failed == 0
    assert rep.killed == "r3"
    assert leftovers(teams) == []


def test_demo_cli_rejects_unknown_robot_and_size():
    runner = CliRunner()
    res = runner.invoke(app, ["demo", "--robots", "3", "--kill", "r9"])
    assert res.exit_code == 2 and "no robot 'r9'" in res.output
    res = runner.invoke(app, ["demo", "--size", "huge"])
    assert res.exit_code == 2 and "unknown size" in res.output


def test_bench_dispatch_reports_latency_and_throughput(tmp_path, teams):
    out = tmp_path / "d.json"
    res = CliRunner().invoke(app, ["bench", "dispatch", "--calls", "30", "--burst", "200", "--window", "32",
                                   "--out", str(out)])
    assert res.exit_code == 0, res.output
    data = json.loads(out.read_text())
    for key in ("p50_ms", "p99_ms", "throughput_per_s", "remote_p50_ms"):
        assert data[key] > 0
    assert data["completed"] == 200
    vs = data["vs_baseline"]["vs"]  # beside the saved figures of fe693da
    assert vs["throughput_per_s"]["baseline"] > 0 and vs["cpu_us"]["this"] > 0
    assert leftovers(teams) == []
