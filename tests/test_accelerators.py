"""Accelerators in the core and the simulator: robots advertise them, programs
that can use one are priced by its slots, hosts run them there and keep them
out of the CPU counts, and a program that needs one fails clearly where the
team has none."""

from __future__ import annotations

import msgspec
import pytest

from ramps.core.accelerators import Accelerator, accelerator_time, parse_accelerator
from ramps.core.events import Received, StartProgram, Submit
from ramps.core.messages import AcceleratorSeen, OffloadRejected, OffloadRequest, decode, encode
from ramps.sim.engine import simulate
from ramps.sim.scenario import FaultSpec, ProgramSpec, RobotSpec, Scenario, ScenarioError
from ramps.testing import FakeTeam

CUDA = [Accelerator(kind="cuda", count=1, speed=20.0)]


def gpu_team(**kw) -> FakeTeam:
    team = FakeTeam({"o": (4, 1.0), "a": (4, 1.0), "g": (4, 1.0)}, accelerators={"g": CUDA}, **kw)
    team.publish()
    return team


def started(team: FakeTeam, robot: str) -> list[StartProgram]:
    return [a for a in team.actions(StartProgram, robot)]


def test_parse_accelerator_reads_kind_count_speed_and_names_bad_text() -> None:
    assert parse_accelerator("cuda") == Accelerator(kind="cuda")
    assert parse_accelerator("cuda:2:20") == Accelerator(kind="cuda", count=2, speed=20.0)
    for bad in ("", "cuda:x", "cuda:0", "cu da", "cuda:1:-3", "a:1:2:3"):
        with pytest.raises(ValueError, match="accelerator"):
            parse_accelerator(bad)


def test_time_on_slots_is_processor_sharing() -> None:
    assert accelerator_time(20.0, 1, 20.0, 0) == 1.0
    assert accelerator_time(20.0, 1, 20.0, 3) == 4.0
    assert accelerator_time(20.0, 2, 20.0, 1) == 1.0  # a free slot


def test_reports_advertise_accelerators_with_the_programs_on_them() -> None:
    team = gpu_team()
    rep = team.nodes["g"].current_report()
    assert rep.accelerators == [AcceleratorSeen("cuda", 1, 20.0, 0)]
    assert team.nodes["o"].current_report().accelerators == []
    # and they cross the wire
    assert decode(encode("g", rep)).msg.accelerators == rep.accelerators


def test_a_program_that_can_use_one_goes_to_the_accelerator_and_is_no_cpu_program_there() -> None:
    team = gpu_team()
    team.handle("o", Submit(program_id="d1", program="detect", work=10.0, accelerator="cuda", accelerator_work=20.0))
    team.deliver()
    (start,) = started(team, "g")
    assert start.accelerator == "cuda" and start.work == 20.0
    g = team.nodes["g"]
    assert g.executor.cpu_programs() == 0 and g.executor.on_accelerators == {"cuda": 1}
    rep = g.current_report()
    assert rep.ramps_running == 0 and rep.accelerators[0].running == 1
    # its CPU seconds say nothing of its work on the accelerator: nothing is learned from it
    team.finish("g", "d1", 1, ok=True, cpu_s=0.5)
    assert team.delivered("d1")[0].ok
    assert team.nodes["o"].origin.learned_runs("detect") == ()


def test_a_busy_accelerator_sends_the_next_program_to_a_cpu_when_that_is_sooner() -> None:
    team = gpu_team()
    # each takes 1 s alone on the accelerator and 3 s on a core: a second one there ends in 2 s, a
    # third would end in 3 s, no sooner than on a free core
    for i in range(3):
        team.handle("o", Submit(program_id=f"d{i}", program="detect", work=3.0, accelerator="cuda",
                                accelerator_work=20.0))
    team.deliver()
    hosts = {a.program_id: (robot, a.accelerator) for _, robot, a in team.log if isinstance(a, StartProgram)}
    on_gpu = [p for p, (robot, kind) in hosts.items() if kind == "cuda"]
    assert len(on_gpu) == 2 and all(hosts[p][0] == "g" for p in on_gpu)
    (cpu,) = [p for p, (_, kind) in hosts.items() if kind == ""]
    assert hosts[cpu][0] in ("o", "a", "g")


def test_programs_without_an_accelerator_still_spread_over_every_core() -> None:
    team = gpu_team()
    team.handle("o", Submit(program_id="d", program="detect", work=10.0, accelerator="cuda", accelerator_work=20.0))
    for i in range(3):
        team.handle("o", Submit(program_id=f"p{i}", program="plan", work=10.0))
    team.deliver()
    hosts = sorted(robot for _, robot, a in team.log if isinstance(a, StartProgram) and not a.accelerator)
    assert hosts == ["a", "g", "o"]  # the accelerator program left g's cores free


def test_a_program_that_needs_one_fails_at_once_where_no_robot_has_it() -> None:
    team = FakeTeam({"o": (4, 1.0), "a": (4, 1.0)})
    team.publish()
    team.handle("o", Submit(program_id="d", program="detect", accelerator="cuda", cpu_fallback=False))
    (out,) = team.delivered("d")
    assert not out.ok and out.error_kind == "refused" and "no robot of the team advertises" in out.error
    assert not team.actions(StartProgram)


def test_a_program_that_needs_one_waits_while_the_robot_that_has_it_is_away() -> None:
    team = gpu_team()
    team.nodes["o"].view.blacklist("g")
    team.handle("o", Submit(program_id="d", program="detect", accelerator="cuda", cpu_fallback=False))
    assert not team.delivered("d") and team.program("d").state.value == "backoff"
    assert not team.actions(StartProgram)
    team.publish("g")  # back: it publishes again
    team.advance(team.now + 3.0)
    (start,) = started(team, "g")
    assert start.accelerator == "cuda"


def test_a_host_without_the_accelerator_turns_the_offer_away() -> None:
    team = gpu_team()
    out = team.handle("a", Received(
        sender="o", msg=OffloadRequest(program_id="x", attempt=1, origin="o", host="a", program="detect",
                                       accelerator="cuda")))
    (rej,) = [a.msg for a in out if hasattr(a, "msg") and isinstance(a.msg, OffloadRejected)]
    assert rej.reason == "accelerator" and not rej.permanent


def test_submit_refuses_nonsense() -> None:
    team = gpu_team()
    with pytest.raises(ValueError, match="accelerator_work"):
        team.handle("o", Submit(program_id="x", program="d", accelerator="cuda", accelerator_work=float("nan")))
    with pytest.raises(ValueError, match="cpu_fallback"):
        team.handle("o", Submit(program_id="y", program="d", cpu_fallback=False))


# ---------------------------------------------------------------- simulator
def mixed(policy: str = "ramps") -> Scenario:
    return Scenario(
        robots=[RobotSpec(name="r1", cores=4), RobotSpec(name="r2", cores=4),
                RobotSpec(name="gpu", cores=4, accelerators=["cuda:1:20"])],
        programs=[ProgramSpec(program="detect", count=12, work=10, accelerator="cuda", accelerator_work=20,
                              origin="r1"),
                  ProgramSpec(program="plan", count=12, work=10, origin="r2")],
        policy=policy,
    ).check()


def test_simulated_accelerator_programs_run_on_its_slots_and_beat_round_robin() -> None:
    ramps, rr = simulate(mixed(), seed=1), simulate(mixed("round_robin"), seed=1)
    assert ramps.completed == rr.completed == 24 and ramps.lost == 0
    detect_hosts = [p.host for p in ramps.programs if p.origin == "r1"]
    assert detect_hosts.count("gpu") >= 9  # 1 s each there, 10 s on a core (the 10th ends as soon on one)
    # round robin puts two thirds of them on cores: it takes longer than the accelerator's queue
    assert ramps.makespan < rr.makespan


def test_scenarios_check_accelerator_fields() -> None:
    with pytest.raises(ScenarioError, match=r"robots\[0\].accelerators\[0\]"):
        Scenario(robots=[RobotSpec(name="r", accelerators=["cuda:zero"])],
                 programs=[ProgramSpec(origin="r")]).check()
    with pytest.raises(ScenarioError, match="cpu_fallback"):
        Scenario(robots=[RobotSpec(name="r")], programs=[ProgramSpec(origin="r", cpu_fallback=False)]).check()


def test_accelerator_programs_are_delivered_once_when_the_accelerator_robot_crashes() -> None:
    sc = msgspec.structs.replace(mixed(), faults=[FaultSpec(at=0.5, robot="gpu", kind="crash")]).check()
    res = simulate(sc, seed=2)
    assert res.completed == 24 and res.lost == 0 and res.duplicated == 0
    assert "gpu" not in {p.host for p in res.programs}  # crashed before any of its programs ended
