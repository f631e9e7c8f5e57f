"""Accelerators on real nodes: a robot that offers an (emulated) one runs the
programs that can use it there, hands them the device, and keeps them out of
its CPU count; the others run on CPUs; a program that needs one fails at
once in a team without any."""

from __future__ import annotations

import pytest
from runtime_team import LocalTeam, wait_for

from ramps.errors import ProgramRefused
from ramps.runtime.accelerators import Grant, resolve
from ramps.runtime.settings import load_settings

pytestmark = pytest.mark.slow


def test_the_setting_reads_auto_none_and_declared_kinds() -> None:
    assert [d.accelerator.kind for d in resolve(["cuda:2:20:emulated"])] == ["cuda"]
    (d,) = resolve(["cuda:2:20:emulated"])
    assert d.emulated and d.accelerator.count == 2 and d.accelerator.speed == 20.0
    assert resolve(["none", "cuda:1"]) == []
    s = load_settings(flags={"robot": "r", "accelerators": ["npu:2:5"]}, default_robot=False)
    assert s.accelerators == ["npu:2:5"]
    with pytest.raises(Exception, match="accelerators"):
        load_settings(flags={"robot": "r", "accelerators": ["cuda:lots"]}, default_robot=False)


def test_an_emulated_slot_is_shared_by_the_programs_on_it(tmp_path) -> None:
    import threading
    import time

    grant = Grant(kind="cuda", device="cuda:0", speed=10.0, emulated=True, slots_dir=str(tmp_path), count=1)
    alone = grant.emulate(1.0)  # 0.1 s of slot time
    walls: list[float] = []
    start = time.monotonic()
    threads = [threading.Thread(target=lambda: walls.append(grant.emulate(1.0))) for _ in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    together = time.monotonic() - start
    # three programs on one slot take about three times as long as one: they take turns
    assert together >= 2.5 * min(alone, 0.1) and max(walls) >= 2.0 * 0.1


def test_programs_that_need_or_can_use_an_accelerator_go_to_the_robot_that_offers_one(tmp_path) -> None:
    """One team for both (each LocalTeam costs seconds of the suite): a program
    that needs an accelerator fails clearly while no robot offers one; once
    g offers an emulated one, it runs there, and so do programs that can use
    one, kept out of g's CPU count."""
    with LocalTeam(["r1", "r2"], tmp_path, cores=2, programs=("where", "needs_cuda")) as t:
        team = t.client("r1")
        with pytest.raises(ProgramRefused, match="advertises"):
            team.submit("needs_cuda", x=1).result(30)
        t.start_node("g", cores=2, extra_args=["--accelerator", "cuda:1:20:emulated"])
        wait_for(lambda: any(r.robot == "g" and r.accelerators for r in team.status().robots), 20,
                 "g's reports advertise its accelerator")
        got = team.submit("needs_cuda", x=2).result(30)
        assert got == {"robot": "g", "device": "cuda:0", "x": 2}
        # 8 programs of 2 CPU units or 0.1 units on the accelerator (5 ms there): every one is sooner on it
        futures = [team.submit("burn_accel", units=2.0, accel_units=0.1) for _ in range(8)]
        results = [f.result(120) for f in futures]
        assert all(r["on"] == "cuda:0" for r in results), results
        assert all(f.host == "g" for f in futures)
        # while they ran, g's reports counted them on its accelerator, not among its CPU programs
        assert all(r.ramps_running == 0 for r in team.status().robots)


def test_a_kinds_slots_are_exclusive_and_the_rest_wait_in_order() -> None:
    from ramps.core.accelerators import Accelerator
    from ramps.runtime.accelerators import AcceleratorProbe, Declared

    probe = AcceleratorProbe("g", [Declared(Accelerator(kind="cuda", count=2), devices=(0, 1))], team="t")
    ran: list[tuple[str, str | None]] = []
    for name in "abcd":
        probe.start((name, 1), "cuda", lambda g, name=name: ran.append((name, g and g.device)))
    assert ran == [("a", "cuda:0"), ("b", "cuda:1")] and probe.waiting() == 2 and probe.held() == 2
    probe.release(("d", 1))  # withdrawn while it waited: never starts
    probe.release(("b", 1))  # b's slot goes to c, on b's device
    assert ran[-1] == ("c", "cuda:1") and probe.waiting() == 0
    probe.release(("a", 1))
    probe.release(("c", 1))
    assert probe.held() == 0 and len(ran) == 3
    probe.start(("x", 1), "npu", lambda g: ran.append(("x", g and g.device)))  # no such kind: a CPU
    assert ran[-1] == ("x", None)
