"""``ramps bench first-calls --testbed``: the bound an emulated team sets, a
round driven through a fake testbed (no root), and one real round on the
testbed (root only)."""

from __future__ import annotations

import json
import os
import time
from contextlib import contextmanager

import pytest

from ramps.bench import firstcalls, firstcalls_testbed
from ramps.bench.firstcalls import describe_round
from ramps.bench.firstcalls_testbed import bench_first_calls_testbed, default_quota, emulated_bound


def test_three_robots_of_one_core_allow_1_5x_two_at_a_time_and_2x_shared():
    # 30 ms of host CPU on an emulated core of 0.6 host cores: 50 ms; one after another 50 ms
    b = emulated_bound(6, 3, 1, 0.6, 0.030, 50.0)
    assert b["c_ms"] == pytest.approx(50.0) and b["host_cores"] == 3 and b["cores_for_1x"] == 6
    assert b["ratio_floor"] == pytest.approx(1.5) and b["shared_ratio_floor"] == pytest.approx(2.0)
    assert b["mode"] == "testbed" and b["team_host_cores"] == pytest.approx(1.8)
    assert b["host_cpu_ms"] == pytest.approx(30.0) and b["core_host_cores"] == pytest.approx(0.6)


def test_three_robots_of_two_cores_allow_1x():
    b = emulated_bound(6, 3, 2, 0.6, 0.030, 100.0)  # 0.3 host cores an emulated core: a call 100 ms
    assert b["c_ms"] == pytest.approx(100.0) and b["host_cores"] == 6
    assert b["ratio_floor"] == pytest.approx(1.0) and b["shared_ratio_floor"] == pytest.approx(1.0)
    # a call alone that took longer than its CPU at an emulated core's share counts as that long
    assert emulated_bound(6, 3, 1, 0.6, 0.030, 90.0, run_alone=80.0)["c_ms"] == pytest.approx(80.0)


def test_the_default_quota_fits_the_robots_in_nine_tenths_of_the_host():
    assert default_quota(3, 2) == pytest.approx(0.6)
    assert default_quota(4, 8) == pytest.approx(1.8)


class _Future:
    def __init__(self, host: str, value: dict) -> None:
        self.host, self.value = host, value

    def add_done_callback(self, fn) -> None:
        fn(self)

    def result(self, timeout: float | None = None) -> dict:
        return self.value


class _Client:
    """Runs each call at once on the robots in turn, writing the trace lines its nodes would."""

    def __init__(self, tb: "_FakeTestbed") -> None:
        self.tb, self.n = tb, 0

    def submit(self, program: str, **kwargs) -> _Future:
        self.n += 1
        host = self.tb.names[self.n % len(self.tb.names)]
        pid, t = f"r1#7-{self.n}", time.monotonic()
        with open(self.tb.log_dir / "r1.trace.jsonl", "a") as f:
            f.write(json.dumps({"t": t, "what": "placed", "program_id": pid}) + "\n")
        with open(self.tb.log_dir / f"{host}.trace.jsonl", "a") as f:
            for dt, what in ((0.0001, "started"), (0.0002, "finished")):
                f.write(json.dumps({"t": t + dt, "what": what, "program_id": pid}) + "\n")
        return _Future(host, {"cpu_seconds": 0.03, "seed": kwargs["seed"]})

    def __enter__(self) -> "_Client":
        return self

    def __exit__(self, *exc: object) -> None:
        self.tb.clients_closed += 1


class _FakeTestbed:
    """What the bench uses of a ``Testbed``: names, robots' node pids, log dir, client."""

    def __init__(self, log_dir) -> None:
        self.names = ["r1", "r2", "r3"]
        self.robots = {r: {"pid": os.getpid()} for r in self.names}  # no fork server: no workers to read
        self.log_dir = log_dir
        self.clients: list[str] = []
        self.clients_closed = 0

    def client(self, robot: str, *, timeout: float) -> _Client:
        self.clients.append(robot)
        return _Client(self)


def test_a_round_on_a_testbed_runs_the_three_phases_and_reads_its_nodes_traces(tmp_path, monkeypatch):
    monkeypatch.setattr(firstcalls_testbed, "SETTLE", 0.0)
    monkeypatch.setattr(firstcalls, "RETIRE_AFTER", -1.5)
    made: list[_FakeTestbed] = []

    @contextmanager
    def make():
        d = tmp_path / f"tb{len(made)}"
        d.mkdir()
        made.append(_FakeTestbed(d))
        yield made[-1]

    lines: list[str] = []
    res = bench_first_calls_testbed(make, robots=3, cores=1, quota=0.6, calls=3, rounds=2, show=lines.append,
                                    keep_logs=tmp_path / "kept")
    assert res["mode"] == "testbed" and res["quota"] == 0.6 and res["cores"] == 1 and res["nodes"] == 3
    assert len(made) == 2 and all(tb.clients == ["r1"] and tb.clients_closed == 1 for tb in made)  # a fresh team a round
    for r in res["rounds"]:
        assert r["bound"]["mode"] == "testbed" and r["bound"]["host_cores"] == 3
        for key in ("cold_at_once", "warm_one_after_another", "warm_at_once"):
            phase = r[key]
            assert phase["hosts"] == ["r2", "r3", "r1"]
            assert [s["program_id"] for s in phase["stages"]] == [f"r1#7-{i}" for i in
                                                                  {"cold_at_once": (1, 2, 3),
                                                                   "warm_one_after_another": (4, 5, 6),
                                                                   "warm_at_once": (7, 8, 9)}[key]]
            assert phase["program_cpu_p50_ms"] == pytest.approx(30.0)
        assert set(r["memory_start"]) == {"r1", "r2", "r3"}
    assert sorted(p.name for p in (tmp_path / "kept" / "round-2").iterdir()) == \
        ["r1.trace.jsonl", "r2.trace.jsonl", "r3.trace.jsonl"]
    assert len(lines) == 2 and "the emulated team's bound for 3 calls" in lines[0]
    assert "on 3 robots of 1 cores" in lines[0] and "the cold burst ran on r1 1, r2 1, r3 1" in lines[0]
    assert describe_round(1, res["rounds"][0]) == lines[0]
    host = res["rounds"][0]["bound"]["host"]  # short calls share the host's cores within a CFS period
    assert host["host_cores"] == firstcalls.host_cores() and host["cpu_ms"] == pytest.approx(
        res["rounds"][0]["warm_one_after_another"]["worker_cpu_per_call_ms"])
    assert f"within a CFS period the robots share this host's {host['host_cores']} cores" in lines[0]


def test_the_command_without_root_says_so_before_making_anything(tmp_path, monkeypatch):
    from typer.testing import CliRunner

    from ramps.cli import app

    monkeypatch.setattr(os, "geteuid", lambda: 1000)
    res = CliRunner().invoke(app, ["bench", "first-calls", "--testbed", "-o", str(tmp_path / "fc.json")])
    assert res.exit_code == 2 and "needs root" in res.output and "3 robots of 2 cores" in res.output
    assert not (tmp_path / "fc.json").exists()


@pytest.mark.slow
@pytest.mark.serial
def test_a_real_round_on_three_emulated_robots(tmp_path):
    """One round of three calls on three robots of one core (0.6 host cores each):
    every call comes back from a robot, every stage is traced, nothing is left; 20-50 s."""
    from test_testbed import REASON, others_leftovers
    from typer.testing import CliRunner

    from ramps.cli import app

    if REASON is not None:
        pytest.skip(REASON)
    pytest.importorskip("ortools")
    out = tmp_path / "fc.json"
    res = CliRunner().invoke(app, ["bench", "first-calls", "--testbed", "--cores", "1", "--quota", "0.6",
                                   "--calls", "3", "-o", str(out), "--keep-logs", str(tmp_path / "logs")])
    assert res.exit_code == 0, res.output
    data = json.loads(out.read_text())
    assert data["mode"] == "testbed" and data["quota"] == 0.6 and data["cores"] == 1
    (r,) = data["rounds"]
    assert r["bound"]["host_cores"] == 3 and r["bound"]["robots"] == 3
    for key in ("cold_at_once", "warm_one_after_another", "warm_at_once"):
        assert set(r[key]["hosts"]) <= {"r1", "r2", "r3"} and len(r[key]["ms"]) == 3
        assert r[key]["stages"] and all(s["started_to_finished_ms"] > 0 for s in r[key]["stages"])
    assert (tmp_path / "logs" / "round-1" / "r1.trace.jsonl").exists()
    assert others_leftovers() == []
