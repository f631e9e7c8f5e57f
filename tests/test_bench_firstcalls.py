"""``ramps bench first-calls``'s own arithmetic: the bound a host's cores
set on six calls at once against the same calls one after another, and the
stages of a call read from the nodes' traces."""

from __future__ import annotations

import json

import pytest

from ramps.bench.firstcalls import bound, describe_round, median_slot, read_traces, stages


def test_the_median_call_of_six_on_two_cores_waits_for_two_calls_cpu():
    assert median_slot(6, 2) == 2  # ends after 1, 1, 2, 2, 3, 3 calls' CPU
    assert median_slot(6, 6) == 1  # a core each
    assert median_slot(6, 1) == 3.5
    assert median_slot(1, 2) == 1


def test_the_bound_is_2x_two_at_a_time_and_3x_shared_when_a_call_alone_is_its_cpu():
    b = bound(6, 2, 0.030, 30.0)
    assert b["ratio_floor"] == pytest.approx(2.0) and b["shared_ratio_floor"] == pytest.approx(3.0)
    assert b["p50_floor_ms"] == pytest.approx(60.0) and b["shared_p50_floor_ms"] == pytest.approx(90.0)
    assert b["cores_for_1x"] == 6
    # what ramps adds to a call alone (here 10 ms) is paid once, not per call waited for
    assert bound(6, 2, 0.030, 40.0)["ratio_floor"] == pytest.approx(70 / 40)
    assert bound(6, 6, 0.030, 30.0)["ratio_floor"] == pytest.approx(1.0)


def test_on_a_loaded_host_a_call_counts_as_long_as_it_ran_alone():
    # 30 ms of CPU that took 140 ms alone (a share of a core): the calls at once wait for that
    b = bound(6, 2, 0.030, 150.0, run_alone_ms=140.0)
    assert b["c_ms"] == 140.0 and b["ratio_floor"] == pytest.approx(1 + 140 / 150)
    assert bound(6, 2, 0.030, 40.0, run_alone_ms=20.0)["c_ms"] == pytest.approx(30.0)  # never below the CPU


def _trace(path, robot, lines):
    path.write_text("".join(json.dumps({"t": t, "robot": robot, "what": w, "program_id": p}) + "\n"
                            for t, w, p in lines) + "not json\n")


def test_stages_come_from_the_origin_and_host_traces_in_submission_order(tmp_path):
    # r1 is the origin; r1#5-10 ran on r2, r1#5-9 on r1 itself (no started/finished lines there)
    _trace(tmp_path / "r1.trace", "r1", [(10.010, "placed", "r1#5-10"), (10.000, "placed", "r1#5-9"),
                                         (10.001, "accepted", "r1#5-9"), (10.030, "delivered", "r1#5-9"),
                                         (10.013, "accepted", "r1#5-10"), (10.062, "delivered", "r1#5-10")])
    _trace(tmp_path / "r2.trace", "r2", [(10.012, "started", "r1#5-10"), (10.060, "finished", "r1#5-10")])
    traced = read_traces([tmp_path / "r1.trace", tmp_path / "r2.trace", tmp_path / "gone.trace"])
    calls = [{"submit": 9.998, "sent": 9.9985, "result": 10.031}, {"submit": 9.999, "sent": 9.9995, "result": 10.065}]
    first, second = stages(calls, traced)
    assert first["program_id"] == "r1#5-9" and second["program_id"] == "r1#5-10"
    assert first["submit_to_placed_ms"] == pytest.approx(2.0) and first["started_to_finished_ms"] == pytest.approx(29)
    assert first["submit_call_ms"] == pytest.approx(0.5)
    assert second["placed_to_started_ms"] == pytest.approx(2.0)
    assert second["started_to_finished_ms"] == pytest.approx(48.0)
    assert second["finished_to_result_ms"] == pytest.approx(5.0)
    assert stages(calls[:1], traced) is None  # a call the traces do not match: no stages rather than wrong ones


def test_a_rounds_line_names_the_ratio_beside_the_bound():
    phase = {"ms": [1.0] * 6, "worker_cpu_per_call_ms": 30.0, "workers_forked": 0, "stages_p50_ms": None,
             "cores_used": 0.4, "hosts": ["r2", "r1", "r1", "r1", "r2", "r3"]}
    r = {"cold_over_sequential_p50": 4.1, "bound": bound(6, 2, 0.030, 30.0), "loadavg_1m": [3.0, 5.5],
         "cold_at_once": phase, "warm_one_after_another": phase}
    line = describe_round(1, r)
    assert "4.1x" in line and "at least 2.0x" in line and "3.0x if all share" in line and "load average 3.0-5.5" in line
    assert "the workers had 0.40 cores in the cold burst" in line
    assert "this host's bound for 6 calls of 30 ms (30 ms CPU) on 2 cores" in line
    assert "the cold burst ran on r1 3, r2 2, r3 1" in line
