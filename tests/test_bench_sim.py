"""``ramps bench sim``: the large team alone, with a fleet's settings."""

from __future__ import annotations

import json

from typer.testing import CliRunner

from ramps.cli import app


def test_bench_sim_large_only_with_settings_writes_its_figures(tmp_path) -> None:
    out = tmp_path / "b.json"
    res = CliRunner().invoke(app, ["bench", "sim", "--large-only", "--robots", "70", "--programs", "140",
                                   "--origins", "2", "--set", "heartbeat_period=5", "--set", "heartbeat_timeout=15",
                                   "--report-period", "5", "--out", str(out)], catch_exceptions=False)
    assert res.exit_code == 0, res.output
    data = json.loads(out.read_text())
    large = data["large"]
    assert data["sweep"] is None
    assert large["completed"] == 140 and large["lost"] == 0 and large["duplicated"] == 0
    assert large["config"] == {"heartbeat_period": 5.0, "heartbeat_timeout": 15.0}
    assert large["report_period"] == 5.0
    assert large["cpu_seconds"] > 0 and large["makespan_over_bound"] >= 1.0
    assert sum(large["robots_by_programs"].values()) <= 70


def test_bench_sim_refuses_an_unknown_setting(tmp_path) -> None:
    res = CliRunner().invoke(app, ["bench", "sim", "--large-only", "--set", "no_such=1", "--out",
                                   str(tmp_path / "b.json")])
    assert res.exit_code != 0 and "no_such" in res.output
