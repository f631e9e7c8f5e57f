"""The battery experiment on real processes (``ramps.lab.battery``): its
figures from the nodes' traces and its report; the experiment itself needs
root and a testbed: ``ramps testbed experiment battery``."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

from typer.testing import CliRunner

from ramps.cli import app
from ramps.lab.battery import BatteryShed, _shed_times, format_report


def _trace(path: Path, *entries: tuple[float, str, str, str, str, int]) -> None:
    path.write_text("".join(json.dumps(dict(t=t, robot=robot, what=what, program_id=pid, other=other,
                                            attempt=attempt, detail="")) + "\n"
                            for t, robot, what, pid, other, attempt in entries))


def test_the_shed_and_re_placement_times_come_from_the_traces(tmp_path: Path) -> None:
    _trace(tmp_path / "r2.trace.jsonl", (9.0, "r2", "battery_low", "", "r2", 0),
           (10.4, "r2", "battery_low", "", "r2", 0))
    _trace(tmp_path / "r1.trace.jsonl", (5.0, "r1", "accepted", "r1#1", "r2", 1),
           (10.5, "r1", "accepted", "r1#1", "r3", 2), (10.7, "r1", "accepted", "r1#2", "r1", 2),
           (11.0, "r1", "accepted", "r1#2", "r3", 3))
    tb = SimpleNamespace(log_dir=tmp_path, tb="t9")
    assert _shed_times(tb, "r2", ["r1#1", "r1#2"], dropped=10.0) == (10.4, 10.7)
    assert _shed_times(tb, "r2", ["r1#1", "r1#3"], dropped=10.0) == (10.4, None)  # one never placed again


def test_the_report_says_what_was_shed_and_how_fast() -> None:
    rep = BatteryShed(robots=3, cores=2, quota=0.25, programs=6, seconds=12.0, drop_at=4.0, publish_period=1.0,
                      low="r2", hosted=["r1#1", "r1#4"], shed_s=0.62, replaced_s=0.66, resumed=2, makespan=31.5,
                      completed=6, failed=0, wrong=0, on_low_after=0, distribution={"r1": 2, "r2": 0, "r3": 4})
    text = format_report(rep)
    assert "r2's battery drops to 10%" in text and "hosts 2 of them" in text
    assert "0.62 s" in text and "0.66 s" in text and "2 resumed" in text and "r3 4" in text


def test_the_command_explains_itself() -> None:
    res = CliRunner().invoke(app, ["testbed", "experiment", "battery", "--help"], env={"COLUMNS": "200"})
    assert res.exit_code == 0 and "--drop-at" in res.output and "battery" in res.output
