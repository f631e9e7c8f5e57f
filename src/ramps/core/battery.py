"""Batteries and energy: a robot's reserve, and what a program costs in energy.

How this works: the driver reads this robot's battery (its state of charge,
0..1) and, where it knows it, the power one busy core draws (watts), and
hands them to the core as ``BatteryMeasured`` with every load report. A
``Reserve`` turns the charge into one bit, *low*: below
``RampsConfig.battery_reserve`` the robot is low, and it is low until its
charge is back at the reserve plus ``battery_hysteresis`` (so a robot whose
charge hovers at the reserve does not flip every report). A low robot

* takes no teammates' programs: its executor turns them away ("battery",
  not permanent: the origin places them elsewhere at once) and its load
  reports say ``low_battery``, which origins read to leave it out of
  placement and relocation (``LoadView.low_battery``);
* hands back what it hosts for teammates, at once: each such program ends
  with a retryable result, and its origin places it elsewhere (from its last
  checkpoint, if it saved one);
* still runs its own programs, here or on teammates.

A robot that reports no battery is never low (mains power, or no figure).

Energy (``RampsConfig.energy_weight``): a program of ``work`` units on a
robot of speed ``s`` drawing ``p`` watts per busy core takes ``work * p /
s`` joules. ``energy_price`` is that per unit of work, divided by the
robot's charge (a joule from a half-empty battery costs twice one from a
full battery or from mains power), so the ``ramps`` policy, given a weight
``w`` in 0..1, ranks hosts by ``t ** (1 - w) * e ** w`` (``t`` its expected
time, ``e`` its price): 0 is the fastest host, 1 the cheapest in energy,
and what lies between trades one for the other whatever the units. A robot
that says nothing of its power is priced at the median of those that do
(at 1 W where none does), so it is neither preferred nor shunned.

Rules: pure functions and plain records, no clock, no I/O.
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Iterable, Sequence
from typing import TYPE_CHECKING, Any

import msgspec

from ramps.core.messages import MAX_LOAD

if TYPE_CHECKING:
    from ramps.core.loadview import LoadView

#: the largest weight ``energy_rank`` uses (1 counts as this: energy all but alone)
ENERGY_ONLY = 0.99


class BatteryMeasured(msgspec.Struct, frozen=True, kw_only=True):
    """The driver read this robot's battery (driver -> core), before a load
    report: ``charge`` its state of charge 0..1 (None: no battery, or none
    readable now), ``power`` the watts one busy core draws (None: not known)."""

    charge: float | None = None
    power: float | None = None


class Reserve:
    """Whether a robot is below its battery reserve, with hysteresis (see
    the module docstring)."""

    __slots__ = ("reserve", "hysteresis", "charge", "low")

    def __init__(self, reserve: float, hysteresis: float) -> None:
        self.reserve = reserve
        self.hysteresis = hysteresis
        #: the latest charge read (None: no battery)
        self.charge: float | None = None
        self.low = False

    def update(self, charge: float | None) -> bool:
        """Take a new reading; True when it changed ``low``. A reading that is
        no number in 0..1 (a broken sensor) counts as no battery."""
        if charge is not None and not (isinstance(charge, (int, float)) and 0.0 <= charge <= 1.0):
            charge = None
        self.charge = None if charge is None else float(charge)
        was = self.low
        if self.charge is None or self.reserve <= 0.0:
            self.low = False
        elif self.low:
            self.low = self.charge < min(1.0, self.reserve + self.hysteresis)
        else:
            self.low = self.charge < self.reserve
        return self.low != was


def sane_power(power: float | None) -> float | None:
    """``power`` if it is a number of watts above 0 that a load report can
    carry (at most ``MAX_LOAD``), else None."""
    if power is None or not isinstance(power, (int, float)) or not (0.0 < power <= MAX_LOAD):
        return None
    return float(power)


def energy_price(speed: float, power: float, charge: float | None) -> float:
    """Joules per work unit on a robot of ``speed`` drawing ``power`` watts
    per busy core, divided by its ``charge`` (None: mains, 1); at least
    1e-300, so a product of prices never reaches 0."""
    price = power / speed if speed > 0 else math.inf
    if charge is not None:
        price /= max(charge, 0.01)
    return max(price, 1e-300)


def fill_powers(powers: Iterable[float | None]) -> list[float]:
    """Each robot's watts per busy core, the median of the known ones (1 W
    where none is known) for those that say nothing."""
    given = list(powers)
    known = [p for p in given if p is not None]
    default = statistics.median(known) if known else 1.0
    return [default if p is None else p for p in given]


def energy_rank(times: list[float], prices: list[float], weight: float) -> list[float]:
    """Each host's rank for placement with ``weight`` (0..1) on energy: its
    time ``t`` times ``(price / cheapest) ** (w / (1 - w))``, which orders
    hosts as ``t ** (1 - w) * price ** w`` does and is a time (seconds) at
    the cheapest host. A weight above ``ENERGY_ONLY`` counts as that: a
    host 1% dearer than the cheapest then ranks as if 2.7 times slower."""
    if weight <= 0.0 or not prices:
        return list(times)
    cheapest = min(prices)
    w = min(weight, ENERGY_ONLY)
    exponent = w / (1.0 - w)
    return [t * math.exp(min(700.0, exponent * math.log(p / cheapest))) for t, p in zip(times, prices)]


def energy_ranks(view: LoadView, rows: Sequence[Sequence[Any]], weight: float) -> list[float]:
    """``energy_rank`` of the ``ramps`` policy's rows (``[t, _, robot, ...,
    speed at 7, ...]``): each host priced by its last report's power and
    battery (``LoadReport.power``, ``battery``; unknown powers filled in)."""
    reports = [view.report_of(row[2]) for row in rows]
    powers = fill_powers([sane_power(r.power) if r is not None else None for r in reports])
    prices = [energy_price(row[7], p, r.battery if r is not None else None) for row, p, r in zip(rows, powers, reports)]
    return energy_rank([row[0] for row in rows], prices, weight)


def rank_by_energy(view: LoadView, rows: list[list[Any]], weight: float) -> list[float] | None:
    """With ``weight`` above 0, the ``ramps`` policy's hosts by time and
    energy: each row's time (``row[0]``) becomes its ``energy_ranks`` and
    the times are returned (``unrank`` puts them back); else None, the rows
    as they were."""
    if weight <= 0.0:
        return None
    times = [row[0] for row in rows]
    for row, rank in zip(rows, energy_ranks(view, rows, weight)):
        row[0] = rank
    return times


def unrank(rows: list[list[Any]], times: list[float] | None) -> None:
    """The rows' times back after ``rank_by_energy`` (nothing if it returned None)."""
    for row, t in zip(rows, times or ()):
        row[0] = t
