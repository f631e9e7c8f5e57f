"""The simulator's host order experiment (``ramps.sim.cpu.CPU.most_work_left_first``):
a robot with more programs than cores runs those with the most work left first."""

from __future__ import annotations

from ramps.sim.cpu import CPU, take_finished


def one_core(now: float = 0.0) -> CPU:
    cpu = CPU(cores=1, speed=1.0, background=0, now=now)
    cpu.add(("long", 1), 3.0, now)
    cpu.add(("short", 1), 1.0, now)
    return cpu


def test_processor_sharing_is_the_default() -> None:
    cpu = one_core()
    assert cpu.next_completion() == (2.0, ("short", 1))  # half a core each
    assert take_finished((cpu,), 2.0) == [("short", 1)]
    assert cpu.next_completion() == (4.0, ("long", 1))


def test_the_most_work_left_runs_first_and_levels_that_meet_share(monkeypatch) -> None:
    monkeypatch.setattr(CPU, "most_work_left_first", True)
    cpu = one_core()
    when, _ = cpu.next_completion()
    assert when == 2.0  # the long one runs alone until it has as much left as the short one
    assert take_finished((cpu,), when) == []
    assert cpu.jobs == {("long", 1): 1.0, ("short", 1): 1.0}
    when, _ = cpu.next_completion()
    assert when == 4.0  # then they share the core and end together
    assert sorted(take_finished((cpu,), when)) == [("long", 1), ("short", 1)]


def test_cores_left_by_the_highest_level_go_to_the_next(monkeypatch) -> None:
    monkeypatch.setattr(CPU, "most_work_left_first", True)
    cpu = CPU(cores=4, speed=2.0, background=0, now=0.0)
    for i in range(6):
        cpu.add(("old", i), 40.0, 0.0)
    cpu.add(("new", 0), 53.0, 0.0)
    # the new one runs on a core of its own; the six old ones share the other three
    when, key = cpu.next_completion()
    assert key == ("new", 0) and abs(when - 13.0 / (2.0 - 1.0)) < 1e-9
    cpu.advance(1.0)
    assert cpu.jobs[("new", 0)] == 51.0 and cpu.jobs[("old", 0)] == 39.0


def test_background_keeps_processor_sharing(monkeypatch) -> None:
    monkeypatch.setattr(CPU, "most_work_left_first", True)
    cpu = CPU(cores=1, speed=1.0, background=1, now=0.0)
    cpu.add(("long", 1), 3.0, 0.0)
    cpu.add(("short", 1), 1.0, 0.0)
    assert cpu.next_completion() == (3.0, ("short", 1))  # a third of the core each
