"""The relocation experiment on real processes (ramps.lab.late_load): its simulator
side, its report and the testbed's node settings; the experiment itself needs root and a
testbed: ``ramps testbed experiment relocation``."""

from __future__ import annotations

import pytest

from ramps.testbed.robots import check_config
from ramps.lab.late_load import RelocationCase, RelocationReport, format_report, simulate_variant


def test_the_simulator_side_moves_the_programs_off_the_busy_robot_and_off_it_does_not():
    kw = dict(robots=3, cores=4, programs=8, seconds=30.0, busy=8, load_at=6.0, checkpoint_every=2.0, seeds=1)
    off, _, off_moves = simulate_variant("relocation off", **kw)
    on, dist, moves = simulate_variant("relocation", **kw)
    ckpt, _, _ = simulate_variant("relocation + checkpoints", **kw)
    assert off_moves == 0 and moves > 0 and dist[0] == 0
    assert ckpt < on < off
    # robots that run programs 1.25x slower than measured: the same decisions, later ends
    slow, slow_dist, _ = simulate_variant("relocation", **kw, speed=0.8)
    assert slow_dist == dist and slow > on * 1.15


def test_the_report_shows_each_variant_beside_the_simulator():
    case = RelocationCase(variant="relocation", makespan=56.0, distribution=[0, 4, 4], moves=3, resumed=0,
                          completed=8, failed=0, wrong=0, sim_makespan=42.0, sim_distribution=[0, 4, 4],
                          sim_moves=3, ratio=1.333, ratio_optimum=1.867, sim_ratio_optimum=1.4, host_factor=1.36,
                          sim_corrected=55.3, corrected_ratio=1.013)
    text = format_report(RelocationReport(robots=3, cores=4, quota=0.2, speed=0.028, programs=8, seconds=30.0,
                                          load_at=6.0, busy=8, checkpoint_every=2.0, hindsight_optimum=30.0,
                                          optimum_distribution=[0, 4, 4], cases=[case]))
    assert "hindsight optimum 30.0 s (0-4-4)" in text
    assert "relocation" in text and "56.0" in text and "55.3  1.01" in text and "0-4-4 / 0-4-4" in text


def test_testbed_node_settings_are_checked_before_any_node_starts():
    assert check_config({"worker_nice": 0, "core": {"relocate": False}}) == {"worker_nice": 0,
                                                                             "core": {"relocate": False}}
    with pytest.raises(ValueError, match="unknown node settings worker_nic, core.relocat"):
        check_config({"worker_nic": 0, "core": {"relocat": False}})
    with pytest.raises(ValueError, match="must be a number, a string or a boolean"):
        check_config({"core": {"relocate": [1]}})
