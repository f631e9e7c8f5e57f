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
