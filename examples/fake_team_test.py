"""Testing code that decides things with ramps, with no processes and no
network: ``ramps.testing.FakeTeam`` joins real core nodes (the same load
server, autonomous programs and executor a robot runs) over an in-memory
network with an explicit clock. You step it: submit, deliver messages,
publish loads, advance time, finish programs, cut a robot off. It runs in
milliseconds and the same steps always give the same result.

    pytest examples/fake_team_test.py
"""

from __future__ import annotations

from collections import Counter

from ramps.core.events import StartProgram, Submit
from ramps.testing import FakeTeam


def started_on(team: FakeTeam) -> dict[str, str]:
    """Where each program was last started: program id -> robot."""
    return {a.program_id: robot for _, robot, a in team.log if isinstance(a, StartProgram)}


def busy_team() -> FakeTeam:
    """Robot o is where the application runs; it is swamped with its own work
    (8 busy processes on 2 cores), and a and b are idle 4-core robots."""
    team = FakeTeam({"o": (2, 1.0), "a": (4, 1.0), "b": (4, 1.0)})
    team.nodes["o"].executor.background = 8.0
    team.publish()  # every robot hears every load report
    return team


def test_work_leaves_a_swamped_robot_and_is_delivered_once() -> None:
    team = busy_team()
    for i in range(6):
        team.handle("o", Submit(program_id=f"p{i}", program="route_plan", work=50.0))
        team.deliver()
    where = started_on(team)
    assert set(where.values()) <= {"a", "b"}  # nothing stays on the swamped robot
    assert max(Counter(where.values()).values()) <= 4  # and no teammate gets more than its cores
    for pid, robot in where.items():
        team.finish(robot, pid, 1, ok=True, value=b"route")
    assert all(len(team.delivered(f"p{i}")) == 1 for i in range(6))


def test_a_robot_cut_off_mid_run_has_its_program_placed_again() -> None:
    team = busy_team()
    team.handle("o", Submit(program_id="p", program="route_plan", work=50.0))
    team.deliver()
    first = started_on(team)["p"]
    team.cut.add(first)  # its network card is switched off: no heartbeats reach o
    team.advance(team.now + 30.0)
    again = started_on(team)["p"]
    assert again != first
    team.finish(again, "p", team.program("p").attempt, ok=True, value=b"route")
    assert [d.host for d in team.delivered("p")] == [again]


if __name__ == "__main__":
    test_work_leaves_a_swamped_robot_and_is_delivered_once()
    test_a_robot_cut_off_mid_run_has_its_program_placed_again()
    print("ok")
