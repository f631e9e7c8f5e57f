"""A program that checkpoints survives its host on real node processes: the
host is killed mid-run, the origin restarts the program on a teammate from
its latest checkpoint (``ramps.resume()``), and the one result says so."""

from __future__ import annotations

import pytest
from runtime_team import PROGRAMS, LocalTeam, _cgroups_work, assert_no_leftovers, wait_for

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module", autouse=True)
def no_leftover_processes():
    yield
    assert_no_leftovers()


def test_a_checkpointing_program_resumes_on_a_teammate_after_its_host_dies(tmp_path):
    with LocalTeam(2, tmp_path, cores=2, programs=PROGRAMS + ("resumable",)) as t:
        team = t.client("r1")
        rr = team.options(policy="round_robin")
        here = rr.submit("resumable", steps=40, dt=0.1)  # round robin: the first runs on the origin ...
        there = rr.submit("resumable", steps=40, dt=0.1)  # ... the second on r2
        wait_for(lambda: there.host == "r2" and (there.progress or 0) >= 0.25, 30,
                 f"the program running on r2 a quarter through ({t.logs()})")
        t.kill_node("r2")
        out = there.result(timeout=60)
        assert out["robot"] == "r1" and out["first"] >= 10, out
        assert there.resumed_from is not None and there.resumed_from >= 0.25 and there.attempts == 2
        assert here.result(timeout=60) == {"robot": "r1", "first": 0} and here.resumed_from is None


@pytest.mark.serial  # busy processes on a robot: alone, so that they slow no other test's robots
@pytest.mark.skipif(not _cgroups_work(), reason="needs root and writable cpu cgroups (each robot's own load)")
def test_a_program_moves_off_a_robot_that_became_busy_and_resumes_there_from_its_checkpoint(tmp_path):
    """A real move: r1 runs one of its two checkpointing burns itself, then its own software
    starts 4 busy processes; the origin moves that burn to idle r2, where it resumes from its
    last checkpoint, and both results arrive once with the same checksum (an uninterrupted burn's)."""
    config = tmp_path / "node.toml"  # react sooner than the defaults (5 s settle, 3 s persist): a shorter test
    config.write_text("[core]\nrelocate_settle = 2.0\nrelocate_persist = 1.0\n")
    t = LocalTeam(2, tmp_path, cores=2)
    t.env["RAMPS_CONFIG"] = str(config)
    with t:
        team = t.client("r1")
        # 4 units: with r1 busy, a move saves far more than relocate_min_gain (5 s); a burn
        # reports progress at its checkpoints only (1/16 of it), so above 0.02 it has saved its place
        burns = [team.options(work=4.0).submit("burn", units=4.0, checkpoint_every=0.25) for _ in range(2)]
        wait_for(lambda: sorted(f.host or "" for f in burns) == ["r1", "r2"] and all((f.progress or 0) > 0.02
                                                                                  for f in burns),
                 30, f"one burn running on each robot ({[(f.host, f.progress) for f in burns]}; {t.logs()})")
        here = next(f for f in burns if f.host == "r1")
        t.add_load("r1", 4)
        # once moved, the burn no longer needs r1 busy: its load stops, so that the two burns
        # on r2 get the host's cores, not a third of them beside r1's busy processes
        wait_for(lambda: here.host == "r2" or here.done(), 120, f"the burn moving off r1 ({t.logs()})")
        for p in t.loads.pop("r1"):
            p.kill()
            p.wait()
        out = here.result(timeout=120)
        assert here.moves == 1 and here.host == "r2", (here.moves, here.host, t.logs())
        assert here.resumed_from is not None and here.resumed_from > 0.0 and out["resumed_at"] > 0
        other = next(f for f in burns if f is not here).result(timeout=120)
        assert other["resumed_at"] == 0 and out["checksum"] == other["checksum"]
        assert out["iterations"] == other["iterations"]
        # `ramps status` shows the move: r1's next load report counts it
        wait_for(lambda: [r.moves for r in team.status().robots if r.robot == "r1"] == [1], 15,
                 f"r1's report counting its move ({team.status()})")
