"""Emulated accelerators on the testbed (ramps.lab.accelerators): its simulator side, its
report and the per-robot node settings run without root; the end-to-end run needs root and
cgroups (skipped otherwise): GPU-class calls land on the accelerator robot's accelerator, the
CPU calls spread over the cores, nothing is lost. No durations are asserted."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import msgspec
import pytest
from test_testbed import REASON, others_leftovers

from ramps.lab.accelerators import (
    AccelReport,
    AccelRepeat,
    Call,
    distribution,
    format_report,
    interleave,
    run_testbed_accelerators,
    simulate_case,
)
from ramps.lab.experiments import read_trace
from ramps.testbed.robots import check_config, node_config_file

SIM = dict(robots=4, cores=2, accelerated=["r4"], accelerator="cuda:1:20", origins=2, gpu=3, cpu=3, units=1.2,
           accel_units=24.0)


def test_each_origin_interleaves_its_calls() -> None:
    assert interleave(3, 3) == ["gpu", "cpu"] * 3
    assert Counter(interleave(2, 5)) == {"gpu": 2, "cpu": 5} and interleave(0, 2) == ["cpu", "cpu"]


def test_the_simulator_side_puts_gpu_calls_on_the_accelerator_and_spreads_the_rest() -> None:
    span, calls = simulate_case(1, speed=0.1, **SIM)
    dist = distribution(calls, ["r1", "r2", "r3", "r4"])
    assert dist["r4"][:2] == [6, 0]  # every GPU-class call on r4's slot (1.2 s each there, 12 s on a core)
    assert sum(v[2] for v in dist.values()) == 6 and all(v[2] <= 2 for v in dist.values())  # one a core
    assert 12.0 < span < 13.0
    # the same team without the speed-up: the slot is no sooner, GPU-class calls spread over the cores too
    _, slow = simulate_case(1, speed=0.1, **{**SIM, "accel_units": 24.0 * 10})
    assert any(c.kind == "gpu" and c.on == "cpu" for c in slow)


def test_the_report_shows_each_repeat_beside_the_simulator() -> None:
    dist = {"r1": [0, 0, 2], "r2": [0, 0, 2], "r3": [0, 0, 2], "r4": [6, 0, 0]}
    run = AccelRepeat(repeat=1, host_load=0.4, node_speeds={"r1": 0.1}, makespan=12.9, distribution=dist,
                      completed=12, failed=0, sim_makespan=12.3, sim_distribution=dist, ratio=1.049, host_factor=1.02,
                      sim_corrected=12.5, corrected_ratio=1.032,
                      calls=[Call(origin="r1", kind="gpu", host="r4", on="cuda:0", submitted=0.0, ended=6.9, wall=6.8)])
    rep = AccelReport(robots=4, cores=2, quota=0.25, speed=0.1, accelerated=["r4"], accelerator="cuda:1:20",
                      origins=2, gpu=3, cpu=3, seconds=12.0, speedup=10.0, units=1.2, accel_units=24.0, seeds=3,
                      repeats=[run])
    text = format_report(rep)
    assert "r4 also offers an emulated cuda:1:20" in text and "1.049" in text and "1.032" in text
    assert "r1 0/0/2 r2 0/0/2 r3 0/0/2 r4 6/0/0 / r1 0/0/2" in text and "median 1.049" in text
    assert msgspec.json.decode(msgspec.json.encode(rep), type=AccelReport) == rep


def test_a_robot_gets_settings_of_its_own_lists_included(tmp_path: Path) -> None:
    assert check_config({"accelerators": ["cuda:1:20:emulated"]}) == {"accelerators": ["cuda:1:20:emulated"]}
    with pytest.raises(ValueError, match="must be a number"):
        check_config({"core": {"relocate": [True]}})  # lists are for node settings only
    config = {"accelerators": ["none"], "core": {"relocate": False}}
    robot_config = {"r4": {"accelerators": ["cuda:1:20:emulated"]}}
    r1, r4 = (node_config_file(tmp_path, robot, config, robot_config).read_text() for robot in ("r1", "r4"))
    assert 'accelerators = ["none"]' in r1 and "relocate = false" in r1
    assert 'accelerators = ["cuda:1:20:emulated"]' in r4 and "relocate = false" in r4 and "none" not in r4


@pytest.mark.slow  # not serial: it checks where calls ran and that none was lost, no time or CPU share
@pytest.mark.skipif(REASON is not None, reason=REASON or "")
def test_gpu_class_calls_run_on_the_accelerator_and_cpu_calls_spread(tmp_path: Path) -> None:
    """3 robots of 2 cores, r3 with an emulated slot; r1 and r2 each submit 3 GPU-class calls
    (3 s on a core, 0.3 s on the slot: all six end sooner there, 1.8 s at most) and 2 CPU calls."""
    rep = run_testbed_accelerators(robots=3, cores=2, quota=0.25, accelerated=1, origins=2, gpu=3, cpu=2,
                                   seconds=3.0, speedup=10.0, repeats=1, seeds=1, timeout=120.0,
                                   keep_logs=tmp_path)
    (run,) = rep.repeats
    assert run.failed == 0 and run.completed == 10
    gpu = [c for c in run.calls if c.kind == "gpu"]
    assert all(c.host == "r3" and c.on == "cuda:0" for c in gpu), gpu
    assert all(c.wall is not None for c in gpu)
    # the CPU calls: none ran where a core was already taken while another robot had one free
    cpu = Counter(c.host for c in run.calls if c.kind == "cpu")
    assert sum(cpu.values()) == 4 and max(cpu.values()) <= 2, cpu
    assert run.distribution["r3"][:2] == [6, 0] and run.sim_distribution["r3"][:2] == [6, 0]
    # nothing lost, nothing delivered twice: each origin's trace
    for origin in ("r1", "r2"):
        delivered = Counter(e.program_id for e in read_trace(tmp_path / "repeat-1" / f"{origin}.trace.jsonl")
                            if e.what == "delivered")
        assert len(delivered) == 5 and set(delivered.values()) == {1}, delivered
    assert others_leftovers() == []
