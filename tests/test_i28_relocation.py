"""Relocation onto an accelerator once a program's runs show it faster there
(``ramps.core.relocation.slot_floor``), on a scenario of the accelerator family."""

from __future__ import annotations

from ramps.experiments.accel_optimum import optimum
from ramps.experiments.accelerators import generate, simulate_variant


def test_a_program_kept_off_a_slot_by_its_declaration_moves_there_once_a_run_shows_it_faster() -> None:
    # misdeclared-37: r3's two "detect" calls declare 45.46 units on cuda and
    # take 18.79. One goes to r2's slot, the other, priced by the declaration,
    # to r1's CPU (21.8 units at speed 1). The slot's run ends 2.5 s in and
    # says the work is 0.41 of the declaration: the CPU copy moves to the slot.
    sc = generate(37)
    res = simulate_variant(sc, "ramps", sc.seed)
    moved = next(p for p in res.programs if p.program_id == "r3#5")
    assert (moved.host, moved.moves, moved.ok) == ("r2", 1, True)
    assert res.completed == 5 and res.lost == 0 and res.duplicated == 0
    assert res.makespan <= 1.01 * optimum(sc).makespan


def test_ramps_blind_to_accelerators_prices_no_slot_for_a_move() -> None:
    # the experiment's variant without the feature: its policy's pools have
    # no slots, so the program stays on the CPU it was placed on
    sc = generate(37)
    res = simulate_variant(sc, "ramps_blind", sc.seed)
    assert all(p.moves == 0 for p in res.programs)


def test_a_program_moves_off_a_crowded_host_for_the_programs_it_leaves_there() -> None:
    # battery-31: r4 puts r4#9 on r1's one fast core beside r3's and r1's own
    # programs; r4 drops below its reserve and r3#7 comes back onto r1 too.
    # At home r4#9 ends no sooner than on r1 by the relocation thresholds,
    # but r1's pool ends much sooner without it: it moves home once.
    from ramps.experiments.battery import generate as battery_scenario
    from ramps.experiments.battery import optimum as battery_optimum
    from ramps.sim.engine import simulate

    sc = battery_scenario(31)
    res = simulate(sc, policy="ramps", seed=1)
    moved = next(p for p in res.programs if p.program_id == "r4#9")
    assert (moved.host, moved.moves, moved.ok) == ("r4", 1, True)
    assert res.lost == 0 and res.duplicated == 0 and res.completed == len(res.programs)
    assert res.makespan <= 1.2 * battery_optimum(sc)  # 1.343 when only its own end counted
