"""The accelerator family's second reference, the CP-SAT optimum told only the
declared accelerator work (``ramps.experiments.accelerators``, ``declared``),
beside the true optimum in each row, summary and table."""

from __future__ import annotations

import io
import math

import msgspec
from rich.console import Console

from ramps.experiments.accel_optimum import optimum
from ramps.experiments.accelerators import (DECLARED_NOTE, AccelReport, generate, print_accelerators, run_scenario,
                                            summarise, told_declarations)
from ramps.sim.scenario import ProgramSpec, RobotSpec, Scenario


def overdeclared() -> Scenario:
    """One ``detect`` of r1 (two cores at speed 0.5, no slot): 26.8 units on a
    CPU, 487 on ``cuda`` and declared as 1,320. r2's one speed-20 slot truly
    runs it in 24.4 s, by the declaration in 66 s; r1's own core in 53.6 s."""
    return Scenario(name="accelerators-misdeclared-small", seed=3,
                    robots=[RobotSpec(name="r1", cores=2, speed=0.5),
                            RobotSpec(name="r2", cores=1, speed=1.0, accelerators=["cuda:1:20"])],
                    programs=[ProgramSpec(program="detect", origin="r1", count=1, work=26.8, accelerator="cuda",
                                          accelerator_work=487.0, accelerator_estimate=1320.0)]).check()


def test_told_the_declarations_replaces_only_the_declared_accelerator_work() -> None:
    sc = overdeclared()
    (told,) = told_declarations(sc).programs
    assert (told.accelerator_work, told.work, told.accelerator_estimate) == (1320.0, 26.8, 1320.0)
    assert told_declarations(generate(0)) == generate(0)  # nothing declared: the same scenario


def test_ramps_is_the_optimum_told_the_declarations_where_that_differs_from_the_true_one() -> None:
    sc = overdeclared()
    row = run_scenario(sc, exact_seconds=1.0, variants=("ramps",))
    assert row.proven and row.declared_proven
    # the true optimum puts it on the slot; told the declaration, on r1's own core
    assert row.optimum < 30.0 and math.isclose(row.declared, 53.6, rel_tol=1e-6)
    assert optimum(sc, time_limit=1.0).hosts == ["r2:cuda"]
    assert math.isclose(row.makespan["ramps"], row.declared, rel_tol=1e-6)
    assert math.isclose(row.ratio_declared["ramps"], 1.0, rel_tol=1e-6)
    assert row.ratio["ramps"] > 1.8  # beside it, never instead of it: the true optimum's ratio stands


def test_the_summary_and_the_table_give_both_references() -> None:
    sc = overdeclared()
    rows = [run_scenario(sc, exact_seconds=1.0, variants=("ramps", "ramps_blind", "round_robin"))]
    s = summarise(rows, "misdeclared")
    assert s.worst["ramps"] > 1.8 and (s.within_3["ramps"], s.within_10["ramps"]) == (0, 0)
    assert s.declared is not None and s.declared_proven == 1
    assert math.isclose(s.declared.worst["ramps"], 1.0, rel_tol=1e-6)
    assert (s.declared.within_3["ramps"], s.declared.within_10["ramps"]) == (1, 1)
    assert "greedy" not in s.declared.median  # the rule with a perfect view is no simulated variant
    report = AccelReport(seed=0, exact_seconds=1.0, rows=rows, summaries=[s, summarise(rows, "all")])
    again = msgspec.json.decode(msgspec.json.encode(report), type=AccelReport)
    assert again.summaries[0].declared == s.declared
    out = io.StringIO()
    print_accelerators(report, Console(file=out, width=120))
    text = out.getvalue()
    assert "ramps / told" in text and "ramps / optimum" in text
    assert DECLARED_NOTE + "\n" in text  # one line
    assert "1.000 / 1.000" in text and "a reference and not a bound" in DECLARED_NOTE
