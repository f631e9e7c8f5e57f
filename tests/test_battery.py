"""Batteries in the core: a robot below its reserve takes no teammates'
programs and hands back those it runs; origins leave it out from its
reports; hysteresis; its own programs still run (``ramps.core.battery``).

Team of ``busy_origin_team``: the origin ``o`` is swamped, so its programs
go to ``a`` (speed 2) first, then ``b`` (speed 1).
"""

from __future__ import annotations

import math

import pytest

from ramps.core.battery import BatteryMeasured, Reserve, energy_price, energy_rank, fill_powers, sane_power
from ramps.core.config import RampsConfig
from ramps.core.events import Deliver, StartProgram, StopProgram, Submit
from ramps.core.messages import MAX_LOAD, LoadReport, OffloadRejected, OffloadRequest, ProgramResult

from corehelpers import busy_origin_team, submit


def _battery(team, robot: str, charge: float | None, power: float | None = None) -> None:
    """``robot``'s driver reads its battery, then publishes its report (as a node does)."""
    team.handle(robot, BatteryMeasured(charge=charge, power=power))
    team.deliver()
    team.publish(robot)
    team.deliver()


# ------------------------------------------------------------------ the reserve
def test_the_reserve_has_hysteresis_so_a_hovering_charge_does_not_flip() -> None:
    r = Reserve(0.2, 0.05)
    seen = []
    for charge in (0.5, 0.21, 0.19, 0.21, 0.24, 0.19, 0.26, 0.22, 0.18):
        changed = r.update(charge)
        seen.append((r.low, changed))
    assert seen == [(False, False), (False, False), (True, True), (True, False), (True, False), (True, False),
                    (False, True), (False, False), (True, True)]


@pytest.mark.parametrize("reading", [None, math.nan, -0.1, 1.5, math.inf, "0.1"])
def test_no_battery_or_a_broken_reading_is_never_low(reading) -> None:
    r = Reserve(0.2, 0.05)
    r.update(0.1)
    assert r.low
    assert r.update(reading) and not r.low and r.charge is None


def test_a_reserve_of_zero_is_off() -> None:
    r = Reserve(0.0, 0.05)
    assert not r.update(0.0) and not r.low


def test_settings_out_of_range_are_refused() -> None:
    for name in ("battery_reserve", "battery_hysteresis", "energy_weight"):
        with pytest.raises(ValueError, match=name):
            RampsConfig(**{name: 1.5})
        with pytest.raises(ValueError, match=name):
            RampsConfig(**{name: -0.1})


# ------------------------------------------------------------------ the team
def test_a_robot_below_its_reserve_says_so_and_origins_leave_it_out() -> None:
    team = busy_origin_team()
    _battery(team, "a", 0.15)
    rep = team.nodes["a"].current_report()
    assert (rep.battery, rep.low_battery) == (0.15, True)
    assert team.nodes["o"].origin.view.low_battery == {"a"}
    submit(team)
    [req] = team.sent(OffloadRequest)
    assert req.host == "b"  # a is faster, but below its reserve
    [note] = team.notes("battery_low", "a")
    assert "charge 15%, reserve 20%" in note.detail and "until 25%" in note.detail


def test_an_offer_that_reaches_a_low_robot_is_turned_away_not_permanently_and_placed_again() -> None:
    team = busy_origin_team()
    team.handle("a", BatteryMeasured(charge=0.1))  # the origin has not heard yet
    team.deliver()
    submit(team)
    team.deliver()
    [rej] = team.sent(OffloadRejected, by="a")
    assert rej.reason == "battery" and not rej.permanent and rej.report is not None and rej.report.low_battery
    assert [r.host for r in team.sent(OffloadRequest)] == ["a", "b"]
    assert "a" in team.nodes["o"].origin.view.low_battery
    team.finish("b", "p", 2, ok=True)
    [d] = team.delivered("p")
    assert d.ok and d.host == "b"


def test_a_robot_that_drops_below_its_reserve_hands_back_what_it_hosts_and_nothing_is_lost() -> None:
    team = busy_origin_team()
    for i in range(3):
        submit(team, pid=f"p{i}")
        team.deliver()
        team.publish()
    on_a = [k for k in team.nodes["a"].executor.running]
    assert on_a, "a (the fastest) hosts some of o's programs"
    _battery(team, "a", 0.1)
    assert not team.nodes["a"].executor.running
    stopped = {(s.program_id, s.attempt) for s in team.actions(StopProgram, "a")}
    assert stopped == set(on_a)
    handed = [r for r in team.sent(ProgramResult, by="a") if r.retryable]
    assert len(handed) == len(on_a) and all("below its battery reserve" in r.error for r in handed)
    # each is placed again at once, elsewhere
    moved = [r for r in team.sent(OffloadRequest) if r.attempt > 1]
    assert len(moved) == len(on_a) and all(r.host != "a" for r in moved)
    for pid, ap in team.nodes["o"].origin.programs.items():
        team.finish(ap.host, pid, ap.attempt, ok=True)
    for i in range(3):
        [d] = team.delivered(f"p{i}")
        assert d.ok and d.host != "a"


def test_a_low_robot_still_runs_its_own_programs() -> None:
    team = busy_origin_team()
    team.nodes["o"].executor.background = 0.0  # o is idle and fast enough for its own program
    _battery(team, "o", 0.05)
    team.handle("o", Submit(program_id="mine", program="x", work=1.0, local_only=True))
    team.deliver()
    assert [s.program_id for s in team.actions(StartProgram, "o")] == ["mine"]
    _battery(team, "o", 0.04)  # still low: nothing of its own is handed back
    assert list(team.nodes["o"].executor.running) == [("mine", 1)]


def test_a_charged_robot_takes_programs_again_past_the_hysteresis() -> None:
    team = busy_origin_team()
    _battery(team, "a", 0.1)
    _battery(team, "a", 0.22)  # above the reserve, below reserve + hysteresis
    assert team.nodes["o"].origin.view.low_battery == {"a"}
    _battery(team, "a", 0.3)
    assert not team.nodes["o"].origin.view.low_battery
    assert team.notes("battery_ok", "a")
    submit(team)
    assert team.sent(OffloadRequest)[-1].host == "a"


def test_a_checkpointed_program_handed_back_resumes_from_its_checkpoint() -> None:
    from ramps.core.events import CheckpointSaved

    team = busy_origin_team()
    submit(team)
    team.deliver()
    [req] = team.sent(OffloadRequest)
    assert req.host == "a"
    team.handle("a", CheckpointSaved(program_id="p", attempt=1, state=b"half", fraction=0.5))
    team.deliver()
    _battery(team, "a", 0.1)
    again = team.sent(OffloadRequest)[-1]
    assert again.host == "b" and again.resume == b"half" and again.resume_fraction == 0.5
    team.finish("b", "p", again.attempt, ok=True)
    [d] = team.delivered("p")
    assert d.ok and d.resumed_from == 0.5


def test_a_robot_without_a_battery_is_never_left_out() -> None:
    team = busy_origin_team()
    _battery(team, "a", None)
    assert team.nodes["a"].current_report().battery is None
    assert not team.nodes["o"].origin.view.low_battery
    submit(team)
    assert team.sent(OffloadRequest)[0].host == "a"


def test_with_the_reserve_off_a_low_battery_changes_nothing() -> None:
    team = busy_origin_team(config=RampsConfig(battery_reserve=0.0))
    _battery(team, "a", 0.01)
    submit(team)
    assert team.sent(OffloadRequest)[0].host == "a"
    assert not team.actions(Deliver)


def test_relocation_never_moves_a_program_onto_a_low_robot() -> None:
    from ramps.core.relocation import price_move

    team = busy_origin_team()
    submit(team)
    team.deliver()
    _battery(team, "b", 0.1)
    ap = team.program("p")
    assert price_move(team.nodes["o"].origin, ap, 1e9, team.now) is None or \
        price_move(team.nodes["o"].origin, ap, 1e9, team.now).host != "b"


# ------------------------------------------------------------------ energy
def test_power_in_reports_is_kept_only_when_a_report_can_carry_it() -> None:
    assert sane_power(12.5) == 12.5
    for bad in (None, 0.0, -1.0, math.nan, math.inf, MAX_LOAD * 2):
        assert sane_power(bad) is None
    team = busy_origin_team()
    _battery(team, "a", 0.9, power=MAX_LOAD * 2)
    assert team.nodes["a"].current_report().power is None
    _battery(team, "a", 0.9, power=6.0)
    assert team.nodes["a"].current_report().power == 6.0


def test_energy_rank_is_time_at_weight_zero_and_price_at_one() -> None:
    times, prices = [10.0, 20.0, 40.0], [4.0, 2.0, 1.0]
    assert energy_rank(times, prices, 0.0) == times
    assert min(range(3), key=energy_rank(times, prices, 1.0).__getitem__) == 2
    assert min(range(3), key=energy_rank(times, prices, 0.5).__getitem__) in (0, 1, 2)
    # t ** (1 - w) * p ** w orders as the rank does
    for w in (0.2, 0.5, 0.8):
        ranks = energy_rank(times, prices, w)
        direct = [t ** (1 - w) * p ** w for t, p in zip(times, prices)]
        assert sorted(range(3), key=ranks.__getitem__) == sorted(range(3), key=direct.__getitem__)
    assert all(math.isfinite(x) for x in energy_rank([1.0, 1.0], [1.0, 1e300], 1.0))


def test_energy_price_is_dearer_from_an_emptier_battery_and_unknown_power_is_the_median() -> None:
    assert energy_price(2.0, 10.0, None) == 5.0
    assert energy_price(2.0, 10.0, 0.5) == 10.0
    assert fill_powers([None, 4.0, 8.0, None]) == [6.0, 4.0, 8.0, 6.0]
    assert fill_powers([None, None]) == [1.0, 1.0]


def test_reports_without_a_battery_leave_the_fields_out_on_the_wire() -> None:
    from ramps.core.messages import decode, encode

    plain = LoadReport(robot="r", incarnation=0, seq=1, cores=1, speed=1.0, cpu_busy=0.0, runnable=0.0,
                       ramps_running=0, ramps_avg=0.0, accepted_total=0, finished_total=0)
    data = encode("r", plain)
    assert b"battery" not in data and b"power" not in data
    full = LoadReport(robot="r", incarnation=0, seq=1, cores=1, speed=1.0, cpu_busy=0.0, runnable=0.0,
                      ramps_running=0, ramps_avg=0.0, accepted_total=0, finished_total=0, battery=0.5,
                      low_battery=True, power=7.5)
    got = decode(encode("r", full)).msg
    assert (got.battery, got.low_battery, got.power) == (0.5, True, 7.5)


@pytest.mark.parametrize("weight, host", [(0.0, "a"), (0.3, "a"), (0.5, "b"), (1.0, "b")])
def test_an_energy_weight_trades_time_for_energy(weight: float, host: str) -> None:
    # a: 25 s at 20 W a core, 10 J a unit; b: 50 s at 4 W, 4 J a unit; o (swamped) says nothing of its power
    team = busy_origin_team(config=RampsConfig(energy_weight=weight))
    _battery(team, "a", None, power=20.0)
    _battery(team, "b", None, power=4.0)
    submit(team)
    [req] = team.sent(OffloadRequest)
    assert req.host == host
    [placed] = team.notes("placed")
    assert placed.detail.startswith("expected 25.0" if host == "a" else "expected 50.0")  # a time, not a rank


def test_energy_from_an_emptier_battery_costs_more() -> None:
    team = busy_origin_team(config=RampsConfig(energy_weight=1.0))
    _battery(team, "a", 1.0, power=8.0)  # 4 J a unit, from a full battery
    _battery(team, "b", 0.3, power=4.0)  # 4 J a unit, from a battery at 30%: 13.3
    submit(team)
    assert team.sent(OffloadRequest)[0].host == "a"


def test_the_previous_release_reads_reports_without_a_battery_and_drops_those_with_one() -> None:
    """docs/wire-compatibility.md: a robot that reports a battery is invisible to 0.1.0 robots."""
    import msgspec

    from ramps.core.messages import encode
    from test_wire_golden import PREVIOUS, _old_wire

    old = _old_wire(PREVIOUS)
    plain = LoadReport(robot="r", incarnation=0, seq=1, cores=1, speed=1.0, cpu_busy=0.0, runnable=0.0,
                       ramps_running=0, ramps_avg=0.0, accepted_total=0, finished_total=0)
    assert old.decode(encode("r", plain)).msg.robot == "r"
    for field, value in (("battery", 0.5), ("low_battery", True), ("power", 6.0)):
        with pytest.raises(old.WireError, match=field):
            old.decode(encode("r", msgspec.structs.replace(plain, **{field: value})))
