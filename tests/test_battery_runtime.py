"""A node reads its robot's battery (``ramps.runtime.battery``): a file, a
command, Linux's power supply class, RAPL for the power; and a real node
driver on the in-memory team (``ramps.testing.memory``) that drops below
its reserve hands back what it hosts in one report period, nothing lost."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import pytest

from ramps.runtime.battery import BatteryReader, Rapl, parse_charge, sysfs_charge
from ramps.runtime.settings import load_settings
from ramps.testing.memory import MemoryTeam


@pytest.mark.parametrize("text, charge", [("87", 0.87), ("87%", 0.87), ("87 %\n", 0.87), ("0.87", 0.87),
                                          ("1.0", 1.0), ("1", 0.01), ("100", 1.0), ("0", 0.0), ("55.5", 0.555),
                                          ("", None), ("x", None), ("101", None), ("-3", None), ("nan", None)])
def test_a_gauge_says_a_percentage_or_a_fraction(text: str, charge: float | None) -> None:
    assert parse_charge(text) == (None if charge is None else pytest.approx(charge))


def _supply(root: Path, name: str, kind: str, capacity: str, present: str | None = None) -> None:
    d = root / name
    d.mkdir(parents=True)
    (d / "type").write_text(kind + "\n")
    (d / "capacity").write_text(capacity + "\n")
    if present is not None:
        (d / "present").write_text(present + "\n")


def test_linux_batteries_are_averaged_and_mains_and_absent_ones_skipped(tmp_path: Path) -> None:
    assert sysfs_charge(tmp_path / "none") is None
    _supply(tmp_path, "AC", "Mains", "0")
    assert sysfs_charge(tmp_path) is None  # mains only: no battery
    _supply(tmp_path, "BAT0", "Battery", "80")
    _supply(tmp_path, "BAT1", "Battery", "40")
    _supply(tmp_path, "BAT2", "Battery", "0", present="0")
    assert sysfs_charge(tmp_path) == pytest.approx(0.6)
    reader = BatteryReader(power_supply=tmp_path)
    assert reader.read() == (pytest.approx(0.6), None)
    assert BatteryReader(power_supply=tmp_path, sysfs=False).read() == (None, None)


def test_a_battery_file_per_robot_and_a_missing_or_odd_one_reads_as_no_battery(tmp_path: Path) -> None:
    reader = BatteryReader(robot="r7", file=str(tmp_path / "battery-{robot}"), power=6.5)
    assert reader.read() == (None, 6.5)  # missing: no battery (logged once)
    (tmp_path / "battery-r7").write_text("42\n")
    assert reader.read() == (pytest.approx(0.42), 6.5)
    (tmp_path / "battery-r7").write_text("full")
    assert reader.read()[0] is None


def test_a_battery_command_runs_off_the_caller_at_most_once_a_period() -> None:
    t = [0.0]
    reader = BatteryReader(command=f"{sys.executable} -c 'print(\"64%\")'", period=1.0, clock=lambda: t[0])
    assert reader.charge() is None  # started; its figure comes when it ends
    deadline = time.monotonic() + 20
    while reader._running and time.monotonic() < deadline:
        time.sleep(0.02)
    assert reader.charge() == pytest.approx(0.64)
    started = reader._started_at
    reader.charge()
    assert reader._started_at == started  # within the period: not run again
    t[0] += 1.5
    reader.charge()
    assert reader._started_at == 1.5


def test_a_failing_command_reads_as_no_battery() -> None:
    reader = BatteryReader(command="exit 3")
    reader.charge()
    deadline = time.monotonic() + 20
    while reader._running and time.monotonic() < deadline:
        time.sleep(0.02)
    assert reader.charge() is None


def test_rapl_power_is_package_joules_over_seconds_over_busy_cores(tmp_path: Path) -> None:
    for name, uj in (("intel-rapl:0", 1_000_000), ("intel-rapl:0:0", 999), ("intel-rapl:1", 2_000_000)):
        (tmp_path / name).mkdir()
        (tmp_path / name / "energy_uj").write_text(str(uj))
    t = [10.0]
    rapl = Rapl(tmp_path, clock=lambda: t[0])
    assert rapl.watts_per_core(2.0) is None  # the first reading only starts the count
    (tmp_path / "intel-rapl:0" / "energy_uj").write_text(str(1_000_000 + 20_000_000))
    t[0] += 2.0
    assert rapl.watts_per_core(2.0) == pytest.approx(5.0)  # 20 J in 2 s over 2 busy cores
    (tmp_path / "intel-rapl:0" / "energy_uj").write_text("5")  # the counter wrapped
    t[0] += 1.0
    assert rapl.watts_per_core(1.0) is None


def test_settings_name_the_sources_and_refuse_a_power_that_is_not_watts() -> None:
    s = load_settings(flags={"robot": "r1", "battery_command": "cat /x", "power_per_core": "rapl"},
                      environ={"RAMPS_BATTERY_FILE": "/run/battery-{robot}"})
    reader = BatteryReader.for_settings(s)
    assert reader.file == Path("/run/battery-r1") and reader.command == "cat /x" and reader.rapl is not None
    with pytest.raises(Exception, match="power_per_core"):
        load_settings(flags={"robot": "r1", "power_per_core": "lots"}, environ={})


def test_a_node_below_its_reserve_hands_back_within_one_report_period_and_nothing_is_lost(tmp_path: Path) -> None:
    files = {r: tmp_path / f"battery-{r}" for r in ("r1", "r2", "r3")}
    for f in files.values():
        f.write_text("90")
    team = MemoryTeam({"r1": (1, 1.0), "r2": (4, 4.0), "r3": (4, 2.0)}, programs=["workprogs:sized"],
                      settings={"battery_file": str(tmp_path / "battery-{robot}"), "battery_sysfs": False})
    app = team.connect("r1")
    try:
        team.run(3.0)
        futs = [app.options(work=200.0).submit("sized", picks=i) for i in range(6)]
        team.run(0.5, complete=False)
        on_r2 = [k for k in team.pools["r2"].jobs]
        assert on_r2, "the fastest robot hosts some of r1's programs"
        files["r2"].write_text("12")  # r2's battery drops below its reserve (20%)
        dropped = team.clock.t
        period = team.nodes["r2"].s.publish_period
        team.run(period + 0.05, complete=False)
        assert not team.nodes["r2"].node.executor.running and not team.pools["r2"].jobs
        assert "r2" not in team.nodes["r1"].node.view.blacklisted()  # handed back, not written off
        assert team.nodes["r2"].node.current_report().low_battery
        assert "r2" in team.nodes["r1"].node.view.low_battery
        assert team.clock.t - dropped <= period + 0.05
        team.run(60.0, until=lambda: all(f.done() for f in futs))
        assert [f.result(0) for f in futs] == list(range(6))
        assert all(f.host != "r2" for f in futs)
        # what an application (and `ramps status`) sees of the batteries
        seen = {r.robot: r for r in app.status().robots}
        assert (seen["r2"].battery, seen["r2"].low_battery) == (0.12, True)
        assert (seen["r1"].battery, seen["r1"].low_battery) == (0.9, False)
        import importlib

        from rich.console import Console

        cli_node = importlib.import_module("ramps.cli.node")  # the module: ``ramps.cli.node`` is also a command
        console = Console(record=True, width=120)
        old, cli_node.out = cli_node.out, console
        try:
            cli_node._print_batteries(app.status())
        finally:
            cli_node.out = old
        rows = [line for line in console.export_text().splitlines() if " r1 " in line or " r2 " in line]
        assert len(rows) == 2 and "12%" in rows[1] and "low" in rows[1] and "90%" in rows[0] and "ok" in rows[0], rows
    finally:
        app.close()
        team.close()


def test_robots_emulated_on_one_machine_do_not_read_its_battery() -> None:
    team = MemoryTeam({"r1": (1, 1.0)})
    try:
        assert team.nodes["r1"].s.battery_sysfs is False
    finally:
        team.close()
    assert load_settings(flags={"robot": "r1"}, environ={"RAMPS_BATTERY_SYSFS": "0"}).battery_sysfs is False
    assert load_settings(flags={"robot": "r1"}, environ={}).battery_sysfs is True
    from ramps.testing.local import LocalTeam

    local = LocalTeam(2)  # nothing starts before ``start``
    try:
        # by variable, which a 0.1.0 node (tests/test_wire_mixed_e2e.py) ignores, where it would refuse the flag
        env = local._env("r1")
        assert "--no-battery-sysfs" not in local.node_argv("r1", 7447, None, None)
        assert load_settings(flags={"robot": "r1"}, environ=env).battery_sysfs is False
    finally:
        local.close()
