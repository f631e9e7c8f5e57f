"""Accelerator placement measured: an accelerator is priced by the work left
on its slots, a program on one is not moved by relocation, and on a few
generated scenarios ramps is no worse than ramps blind to accelerators and
close to the CP-SAT optimum."""

from __future__ import annotations

from ramps.core.accelerators import Accelerator
from ramps.core.events import StartProgram, Submit
from ramps.experiments.accelerators import BlindPolicy, generate, run_scenario, simulate_variant
from ramps.sim.engine import simulate
from ramps.sim.scenario import ProgramSpec, RobotSpec, Scenario
from ramps.testing import FakeTeam


def hosts(team: FakeTeam) -> dict[str, tuple[str, str]]:
    return {a.program_id: (robot, a.accelerator) for _, robot, a in team.log if isinstance(a, StartProgram)}


def test_a_slot_busy_with_short_programs_is_priced_by_their_work_left() -> None:
    team = FakeTeam({"o": (1, 1.0), "g": (1, 1.0)}, accelerators={"g": [Accelerator(kind="cuda", speed=10.0)]})
    team.publish()
    for i in range(4):  # 0.1 s each on the slot, 5 s on a core: all four on the slot
        team.handle("o", Submit(program_id=f"s{i}", program="detect", work=5.0, accelerator="cuda",
                                accelerator_work=1.0))
    # 1 s alone on the slot, 2 s on o's core: beside the four it ends after 1.4 s there (by their count: 5 s)
    team.handle("o", Submit(program_id="big", program="detect", work=2.0, accelerator="cuda", accelerator_work=10.0))
    team.deliver()
    placed = hosts(team)
    assert all(placed[f"s{i}"] == ("g", "cuda") for i in range(4))
    assert placed["big"] == ("g", "cuda")


def test_blind_placement_prices_every_robot_by_cpu_work() -> None:
    team = FakeTeam({"o": (1, 1.0), "g": (1, 1.0)}, accelerators={"g": [Accelerator(kind="cuda", speed=20.0)]})
    for node in team.nodes.values():
        node.policy = node.origin.policy = BlindPolicy()
    team.publish()
    # 1 s on the slot, 10 s on either core: blind, it stays at home
    team.handle("o", Submit(program_id="d", program="detect", work=10.0, accelerator="cuda", accelerator_work=20.0))
    team.deliver()
    assert hosts(team)["d"] == ("o", "")


def test_programs_on_an_accelerator_are_not_moved_by_relocation() -> None:
    sc = Scenario(robots=[RobotSpec(name="r1", cores=2, accelerators=["cuda:2:30"]),
                          RobotSpec(name="r2", cores=2, accelerators=["cuda:2:20"])],
                  programs=[ProgramSpec(program="detect", origin="r1", count=3, work=23.2, accelerator="cuda",
                                        accelerator_work=165.7),
                            ProgramSpec(program="detect", origin="r1", count=3, work=12.7, accelerator="cuda",
                                        accelerator_work=110.4)]).check()
    res = simulate(sc, seed=1, trace=True)
    assert res.completed == 6 and res.lost == 0 and res.duplicated == 0
    assert not [t for t in res.trace if t.what == "moving"]
    assert all(p.attempts == 1 for p in res.programs)


#: the mixed and strict scenarios among the family's first ten (seed 0)
FEW = (0, 1, 5, 6)
#: how far above the optimum ramps may end on them (measured: 1.135, 1.109, 1.0, 1.0)
BOUND = 1.2


def test_on_a_few_scenarios_ramps_beats_blind_placement_and_is_near_the_optimum() -> None:
    for i in FEW:
        row = run_scenario(generate(i), exact_seconds=2.0, variants=("ramps", "ramps_blind"))
        assert row.proven, row.scenario
        assert row.ratio["ramps"] <= row.ratio["ramps_blind"] + 1e-9, row
        assert row.ratio["ramps"] <= BOUND, row
        assert row.ratio["ramps"] >= 0.99, row  # the reference is an optimum: nothing ends much before it


def test_variants_are_deterministic_on_a_seed() -> None:
    sc = generate(3)
    first, again = simulate_variant(sc, "ramps_blind", 5), simulate_variant(sc, "ramps_blind", 5)
    assert first.makespan == again.makespan
    assert [p.host for p in first.programs] == [p.host for p in again.programs]


def test_the_command_prints_the_table_and_writes_json(tmp_path) -> None:
    import json

    from typer.testing import CliRunner

    from ramps.cli import app

    out = tmp_path / "acc.json"
    res = CliRunner().invoke(app, ["sim", "accelerators", "-n", "2", "--exact-seconds", "1", "-o", str(out)],
                             env={"COLUMNS": "160"}, terminal_width=160)
    assert res.exit_code == 0, res.output
    assert "ramps blind" in res.output and "mixed" in res.output and "strict" in res.output
    data = json.loads(out.read_text())
    assert [r["scenario"] for r in data["rows"]] == ["accelerators-mixed-0", "accelerators-strict-1"]
    assert {s["family"] for s in data["summaries"]} == {"mixed", "strict", "all"}
