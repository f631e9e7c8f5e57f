"""What runs on an accelerator teach (``ramps.core.learning``): the host tells
the work a run took there (the seconds it held a slot at the slot's speed, or
processor sharing of the slots), its origin learns it apart from the CPU work,
places the next calls by it, and a slot whose programs overran their estimate
is no longer taken for free."""

from __future__ import annotations

import pytest

from ramps.core.accelerators import Accelerator, work_left
from ramps.core.events import Note, StartProgram, Submit
from ramps.core.learning import learned_name
from ramps.core.messages import OffloadRequest, ProgramResult
from ramps.runtime.accelerators import AcceleratorProbe, Declared
from ramps.sim.engine import Simulator
from ramps.sim.scenario import ProgramSpec, RobotSpec, Scenario
from ramps.testing import FakeTeam

CUDA = [Accelerator(kind="cuda", count=1, speed=20.0)]


def gpu_team() -> FakeTeam:
    team = FakeTeam({"o": (4, 1.0), "g": (4, 1.0)}, accelerators={"g": CUDA})
    team.publish()
    return team


def detect(pid: str, declared: float = 20.0) -> Submit:
    return Submit(program_id=pid, program="detect", work=10.0, accelerator="cuda", accelerator_work=declared)


def results(team: FakeTeam) -> list[ProgramResult]:
    return team.sent(ProgramResult, by="g")


def test_the_host_tells_the_work_a_run_took_on_its_accelerator() -> None:
    team = gpu_team()
    team.handle("o", detect("d1"))
    team.deliver()
    team.now += 5.0  # alone on the slot: 5 s at speed 20 is 100 units, five times the declaration
    team.finish("g", "d1", 1, ok=True, cpu_s=0.3)
    assert results(team)[-1].work_done == pytest.approx(100.0)
    # a driver whose slots are exclusive says how long the program held one (it may have waited for it)
    team.handle("o", detect("d2"))
    team.deliver()
    team.now += 10.0
    team.finish("g", "d2", 1, ok=True, slot_s=4.0)
    assert results(team)[-1].work_done == pytest.approx(80.0)


def test_the_origin_learns_accelerator_work_apart_and_places_the_next_call_by_it() -> None:
    team = gpu_team()
    origin = team.nodes["o"].origin
    team.handle("o", detect("d1"))
    team.deliver()
    team.now += 5.0
    team.finish("g", "d1", 1, ok=True)
    name = learned_name("detect", "cuda")
    assert name == "detect on cuda" and list(origin.learned_runs(name)) == pytest.approx([5.0])
    assert origin.learned_runs("detect") == () and origin.work_estimate(detect("x")) == 10.0  # the CPU work stays
    assert origin.accelerator_work_estimate(detect("x")) == pytest.approx(100.0)
    assert origin.accelerator_work_estimate(detect("x", declared=2.0)) == pytest.approx(10.0)  # per declared unit
    assert origin.learned_work()[name] == pytest.approx(100.0)
    [note] = [n for n in team.notes("misdeclared") if isinstance(n, Note)]
    assert "detect on cuda declared 20 work units, took 100" in note.detail
    # the host's CPU speed is not corrected by a run on its accelerator
    assert team.nodes["o"].host_speeds.factor.get("g", 1.0) == 1.0
    # the next call (5 s there, 10 s on a core) is offered with the work it will take there
    team.handle("o", detect("d2"))
    team.deliver()
    offer = team.sent(OffloadRequest, to="g")[-1]
    assert offer.program_id == "d2" and offer.accelerator == "cuda" and offer.work == pytest.approx(100.0)
    # one that would take 20 s there now goes to a core (10 s)
    team.handle("o", detect("d3", declared=40.0))
    team.deliver()
    assert [a.program_id for a in team.actions(StartProgram, "o")] == ["d3"]


def test_a_program_that_overran_its_estimate_is_priced_as_one_of_unknown_work() -> None:
    # placed at 0 with 20 units on a speed-10 slot: done by 2 s by its estimate; at 5 s still running
    assert work_left([(20.0, 0.0), (100.0, 0.0)], 5.0, 1, 10.0, 2) == [75.0]
    assert work_left([(20.0, 0.0)], 1.0, 1, 10.0, 1) == [10.0]
    team = gpu_team()
    team.handle("o", detect("d1"))  # 1 s there by its declaration
    team.deliver()
    team.advance(5.0)
    team.publish("g")  # g still runs it: it took more than declared, how much more is not known
    assert team.nodes["g"].current_report().accelerators[0].remaining == [0.0]  # nothing left by g's estimate
    [row] = team.nodes["o"].view.accelerator_rows(team.now, "cuda")
    assert row[3] == 1.0 and row[4] == []


def test_a_repeated_misdeclared_program_moves_off_the_accelerator_once_learned() -> None:
    # 20 calls 6 s apart, declared 20 units on the slot (2 s) and truly 200 (20 s), 10 s on a core
    sc = Scenario(name="learn", seed=1, robots=[
        RobotSpec(name="o", cores=2), RobotSpec(name="g", cores=2, accelerators=["cuda:1:10"]),
        RobotSpec(name="c1", cores=2), RobotSpec(name="c2", cores=2)],
        programs=[ProgramSpec(program="detect", origin="o", count=20, work=10.0, accelerator="cuda",
                              accelerator_work=200.0, accelerator_estimate=20.0, spacing=6.0)])
    res = Simulator(sc, seed=1).run()
    stats = next(s for s in res.statistics if s.robot == "o")
    assert stats.learned_work["detect on cuda"] == pytest.approx(200.0)
    on_gpu = sum(1 for p in res.programs if p.host == "g")
    assert on_gpu <= 6 and res.completed == 20 and res.makespan < 150.0  # all 20 on the slot: 400 s


def test_the_probe_says_how_long_a_program_held_its_slot() -> None:
    probe = AcceleratorProbe("g", [Declared(Accelerator(kind="cuda", count=1), devices=(0,))], team="t")
    probe.start(("a", 1), "cuda", lambda g: None)
    probe.start(("b", 1), "cuda", lambda g: None)
    assert probe.release(("b", 1)) is None  # stopped while it waited: it held none
    held = probe.release(("a", 1))
    assert held is not None and held >= 0.0
    assert probe.release(("a", 1)) is None
