"""This robot's battery and power, as its node reads them before each load report.

How this works: ``BatteryReader.read(busy)`` returns (charge 0..1 or None,
watts per busy core or None), which the node hands its core as
``ramps.core.battery.BatteryMeasured``; below ``[core] battery_reserve``
the robot takes no teammates' programs and hands back those it runs. The
charge comes from the first of:

* ``battery_file``: a file holding a percentage (``87``, ``87%``) or a
  fraction (``0.87``), read each time; ``{robot}`` in its path becomes the
  robot's name (one config file for a fleet; the testbed writes one file a
  robot). A file that is missing or holds anything else reads as no battery.
* ``battery_command``: a shell command that prints the same, run at most
  once a report period off the node's thread (a slow one never holds a
  report back: the latest figure is used), killed after ``COMMAND_TIMEOUT``;
  e.g. ``upower -i $(upower -e | grep BAT) | awk '/percentage/ {print $2}'``
  or a script that asks the robot's own battery management.
* Linux's power supply class (``battery_sysfs``, on by default): every
  ``/sys/class/power_supply/*`` of type ``Battery`` that is present, its
  ``capacity`` (percent); several are averaged. None on a machine without.

The power per busy core (``power_per_core``) is a number of watts, or
``rapl``: Intel RAPL's package energy counters
(``/sys/class/powercap/intel-rapl:N/energy_uj``) over the time since the
last reading, divided by the cores busy meanwhile (at least one): an upper
estimate, since the package's idle power is counted in. None where neither.

Every failure reads as "no figure" and is logged once per source, never
raised: a robot with a broken gauge is treated as one without a battery.
"""

from __future__ import annotations

import logging
import subprocess
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from ramps.runtime.settings import NodeSettings

log = logging.getLogger("ramps.node")

#: where Linux lists power supplies and RAPL domains
POWER_SUPPLY = Path("/sys/class/power_supply")
POWERCAP = Path("/sys/class/powercap")
#: seconds a battery command may run before it is killed
COMMAND_TIMEOUT = 5.0


def parse_charge(text: str) -> float | None:
    """A state of charge 0..1 from a gauge's text (its first word): a number
    with a decimal point of at most 1 is a fraction (``0.87``, ``1.0``),
    anything else a percentage (``87``, ``87.5``, ``87%``, ``1`` is 1%);
    None for a word that is no number in 0..100."""
    words = text.split()
    if not words:
        return None
    word = words[0]
    percent = word.endswith("%") or (len(words) > 1 and words[1] == "%")
    word = word.rstrip("%")
    try:
        value = float(word)
    except ValueError:
        return None
    if not 0.0 <= value <= 100.0:  # NaN too
        return None
    if not percent and "." in word and value <= 1.0:
        return value
    return value / 100.0


def sysfs_charge(root: Path = POWER_SUPPLY) -> float | None:
    """The mean ``capacity`` of the batteries Linux lists under ``root``
    (type ``Battery``, present), or None where it lists none."""
    charges = []
    try:
        supplies = sorted(root.iterdir())
    except OSError:
        return None
    for d in supplies:
        try:
            if (d / "type").read_text().strip() != "Battery":
                continue
            present = d / "present"
            if present.exists() and present.read_text().strip() == "0":
                continue
            charge = parse_charge((d / "capacity").read_text())
        except OSError:
            continue
        if charge is not None:
            charges.append(charge)
    return sum(charges) / len(charges) if charges else None


class Rapl:
    """Package power from Intel RAPL's energy counters, per busy core."""

    def __init__(self, root: Path = POWERCAP, clock: Callable[[], float] = time.monotonic) -> None:
        # the packages (intel-rapl:0, intel-rapl:1), not their subdomains (intel-rapl:0:0)
        self.files = sorted(p / "energy_uj" for p in root.glob("intel-rapl:*") if p.name.count(":") == 1)
        self.clock = clock
        self._last: tuple[float, float] | None = None

    def _energy(self) -> float | None:
        total = 0.0
        for f in self.files:
            try:
                total += float(f.read_text())
            except (OSError, ValueError):
                return None
        return total / 1e6 if self.files else None

    def watts_per_core(self, busy: float) -> float | None:
        """Joules since the last call over its seconds and over the cores busy
        (at least one); None on the first call, a wrapped counter or none."""
        joules, now = self._energy(), self.clock()
        last, self._last = self._last, (None if joules is None else (joules, now))
        if joules is None or last is None or now <= last[1] or joules < last[0]:
            return None
        return (joules - last[0]) / (now - last[1]) / max(1.0, busy)


class BatteryReader:
    """Reads the battery (and the power per busy core) from the sources the
    settings name (module docstring). ``read`` never blocks on a command
    and never raises."""

    def __init__(self, *, robot: str = "", file: str = "", command: str = "", sysfs: bool = True,
                 power: float | str | None = None, period: float = 1.0, power_supply: Path = POWER_SUPPLY,
                 powercap: Path = POWERCAP, clock: Callable[[], float] = time.monotonic) -> None:
        self.file = Path(file.replace("{robot}", robot)) if file else None
        self.command = command
        self.sysfs = sysfs
        self.power_supply = power_supply
        self.period = period
        self.clock = clock
        self.power = power if isinstance(power, (int, float)) else None
        self.rapl = Rapl(powercap, clock) if power == "rapl" else None
        #: the command's latest figure, and when it was last started (one run at a time)
        self._from_command: float | None = None
        self._started_at = -float("inf")
        self._running = False
        self._lock = threading.Lock()
        self._warned: set[str] = set()

    @classmethod
    def for_settings(cls, s: NodeSettings) -> "BatteryReader":
        """The reader a node of settings ``s`` (``NodeSettings``) uses."""
        return cls(robot=s.robot, file=s.battery_file, command=s.battery_command, sysfs=s.battery_sysfs,
                   power=s.power_per_core, period=s.publish_period)

    def read(self, busy: float = 0.0) -> tuple[float | None, float | None]:
        """(charge 0..1 or None, watts per busy core or None); ``busy`` is the
        cores busy since the last report (for ``rapl``)."""
        power = self.power if self.rapl is None else self.rapl.watts_per_core(busy)
        return self.charge(), power

    def charge(self) -> float | None:
        if self.file is not None:
            try:
                charge = parse_charge(self.file.read_text())
            except OSError as exc:
                self._warn("file", f"cannot read the battery file {self.file}: {exc.strerror or exc}")
                return None
            if charge is None:
                self._warn("file-text", f"the battery file {self.file} holds no percentage or fraction")
            return charge
        if self.command:
            self._poll_command()
            return self._from_command
        return sysfs_charge(self.power_supply) if self.sysfs else None

    def _poll_command(self) -> None:
        with self._lock:
            now = self.clock()
            if self._running or now - self._started_at < self.period:
                return
            self._running, self._started_at = True, now
        threading.Thread(target=self._run_command, name="ramps-battery", daemon=True).start()

    def _run_command(self) -> None:
        charge = None
        try:
            done = subprocess.run(self.command, shell=True, capture_output=True, text=True,
                                  timeout=COMMAND_TIMEOUT, check=False)
            charge = parse_charge(done.stdout) if done.returncode == 0 else None
            if charge is None:
                self._warn("command", f"the battery command {self.command!r} gave no percentage or fraction "
                                      f"(exit {done.returncode}: {(done.stdout or done.stderr).strip()[:200]!r})")
        except (OSError, subprocess.SubprocessError) as exc:
            self._warn("command", f"the battery command {self.command!r} failed: {exc}")
        finally:
            with self._lock:
                self._from_command, self._running = charge, False

    def _warn(self, key: str, text: str) -> None:
        if key not in self._warned:
            self._warned.add(key)
            log.warning("%s: the robot counts as having no battery until it reads one", text)
        else:
            log.debug(text)
