"""Simulated batteries and the energy a run uses.

How this works: a robot whose ``RobotSpec`` gives a ``battery`` (its state
of charge at the start, 0..1) drains by ``drain`` for every second one of
its cores is busy (its programs and its own busy processes alike), and a
``battery`` fault sets its charge (``FaultSpec.charge``: a drop, or a
charge). Its load publisher reads the battery before each report, as a
node does (``ramps.runtime.battery``), and hands the core
``BatteryMeasured`` with the robot's ``power`` (watts per busy core), so a
robot that drops below its reserve hands back its teammates' programs
within one report period. Robots with neither battery nor power get no
such event: a scenario without them has no battery events.

Energy: every robot's busy core-seconds times its ``power`` (1 W where the
scenario gives none, so the figure is then its busy core-seconds), counted
at each report and at the end of the run (``SimResult.energy``).
"""

from __future__ import annotations

from ramps.core.battery import BatteryMeasured
from ramps.sim.cpu import CPU
from ramps.sim.scenario import RobotSpec


class _Battery:
    __slots__ = ("spec", "charge", "joules", "cpu", "busy_seen")

    def __init__(self, spec: RobotSpec) -> None:
        self.spec = spec
        self.charge = spec.battery
        self.joules = 0.0
        #: the CPU last sampled and its busy core-seconds then (a reboot makes a new CPU)
        self.cpu: CPU | None = None
        self.busy_seen = 0.0


class Batteries:
    """Every robot's battery and energy in one simulation."""

    def __init__(self, team: list[RobotSpec]) -> None:
        self._robots = {spec.name: _Battery(spec) for spec in team}

    def _advance(self, b: _Battery, cpu: CPU, now: float) -> None:
        busy = cpu.busy_seconds(now)
        if cpu is not b.cpu:
            b.cpu, b.busy_seen = cpu, 0.0
        spent, b.busy_seen = max(0.0, busy - b.busy_seen), busy
        b.joules += spent * (b.spec.power if b.spec.power is not None else 1.0)
        if b.charge is not None:
            b.charge = max(0.0, b.charge - spent * b.spec.drain)

    def sample(self, robot: str, cpu: CPU, now: float) -> list[BatteryMeasured]:
        """What ``robot``'s node reads before a report at ``now``: its charge
        and power (none for a robot that has neither)."""
        b = self._robots[robot]
        self._advance(b, cpu, now)
        if b.charge is None and b.spec.power is None:
            return []
        return [BatteryMeasured(charge=b.charge, power=b.spec.power)]

    def set_charge(self, robot: str, cpu: CPU, now: float, charge: float) -> None:
        """A ``battery`` fault: the robot's charge is ``charge`` from now."""
        b = self._robots[robot]
        self._advance(b, cpu, now)
        b.charge = charge

    def finish(self, cpus: dict[str, CPU], now: float) -> tuple[dict[str, float], dict[str, float]]:
        """(joules each robot used, the charge of each robot with a battery) at the end."""
        for name, cpu in cpus.items():
            self._advance(self._robots[name], cpu, now)
        return ({name: round(b.joules, 6) for name, b in self._robots.items()},
                {name: round(b.charge, 6) for name, b in self._robots.items() if b.charge is not None})
