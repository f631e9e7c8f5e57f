"""Do identical robots measure themselves alike? Start an emulated team
again and again and read the speed each node found, as a user's nodes do.

How this works: each start is a fresh ``Testbed`` of identical robots (the
same quota and cores, nothing handed in with ``--speed``: every node
measures itself, as it does on a real robot), optionally with the robots'
own busy processes starting beside the nodes. The speed each node measured
at boot comes from its log's join line; the speed it reports later (after
its first re-measurements, ``ramps.core.speed.next_remeasure``) from its
load reports, read by a client in the root namespace, and its own figure
then, before it pools with robots of its class (``ramps.core.speed.SpeedClass``),
from its trace.
The figure of a start is the spread: the fastest robot's speed over the
slowest's.
"""

from __future__ import annotations

import re
import time
from typing import Callable

import msgspec

#: seconds after the team is up at which the reported speeds are read
READ_AT = (2.0, 10.0, 20.0)
_JOINED = re.compile(r"joined team \S+: \d+ cores, speed ([0-9.eE+-]+)")


def spread(speeds: dict[str, float]) -> float:
    """The fastest robot's speed over the slowest's (inf if one has none)."""
    values = list(speeds.values())
    return max(values) / min(values) if values and min(values) > 0 else float("inf")


def reported_speeds(obs, robots: int, timeout: float = 10.0) -> dict[str, float]:
    """robot -> the speed in its latest load report (0.0: none yet), once every
    robot has reported or ``timeout`` seconds have passed."""
    names = [f"r{i}" for i in range(1, robots + 1)]
    deadline = time.monotonic() + timeout
    while True:
        seen = {row["robot"]: float(row["speed"]) for row in obs.view() if "speed" in row}
        if all(r in seen for r in names) or time.monotonic() >= deadline:
            return {r: seen.get(r, 0.0) for r in names}
        time.sleep(0.2)


class SpeedStart(msgspec.Struct, kw_only=True):
    #: robot -> the speed its node measured at boot
    boot: dict[str, float]
    #: seconds after the team was up -> robot -> the speed in its latest report
    reported: dict[str, dict[str, float]]
    #: the same moments -> robot -> its own figure, before pooling with its class
    own: dict[str, dict[str, float]] = {}
    #: robot -> its re-measurements from its trace: [moment on the team's grid
    #: (Unix time), that measurement's own figure, the node's figure after it]
    measured: dict[str, list[list[float]]] = {}


class SpeedsReport(msgspec.Struct, kw_only=True):
    robots: int
    cores: int
    quota: float
    loaded: int
    starts: list[SpeedStart]

    def table(self) -> str:
        heads = ["start", "boot speeds", "boot spread"] + [f"spread at +{t:g} s" for t in READ_AT] + \
            [f"own figures' spread at +{READ_AT[-1]:g} s"]
        lines = [" | ".join(heads)]
        for i, s in enumerate(self.starts, 1):
            boot = " ".join(f"{s.boot.get(r, 0):.4f}" for r in sorted(s.boot))
            cells = [str(i), boot, f"{spread(s.boot):.3f}"]
            cells += [f"{spread(s.reported.get(str(t), {})):.3f}" for t in READ_AT]
            cells.append(f"{spread(s.own.get(str(READ_AT[-1]), {})):.3f}")
            lines.append(" | ".join(cells))
        last = str(READ_AT[-1])
        within = sum(1 for s in self.starts if spread(s.boot) <= 1.05)
        later = sum(1 for s in self.starts if spread(s.reported.get(last, {})) <= 1.05)
        own = sum(1 for s in self.starts if spread(s.own.get(last, {})) <= 1.05)
        lines.append(f"within 5% of each other: {within}/{len(self.starts)} at boot, "
                     f"{later}/{len(self.starts)} at +{READ_AT[-1]:g} s "
                     f"({own}/{len(self.starts)} by their own figures, before pooling)")
        return "\n".join(lines)


_MEASURED = re.compile(r"([0-9.eE+-]+) at ([0-9.]+), node figure ([0-9.eE+-]+)")


def measurements(log_dir, names: list[str]) -> dict[str, list[list[float]]]:
    """robot -> its re-measurements, from the ``speed_measured`` lines of its trace."""
    out: dict[str, list[list[float]]] = {}
    for r in names:
        rows = []
        try:
            lines = (log_dir / f"{r}.trace.jsonl").read_text(errors="replace").splitlines()
        except OSError:
            lines = []
        for line in lines:
            if '"speed_measured"' not in line:
                continue
            m = _MEASURED.search(msgspec.json.decode(line).get("detail", ""))
            if m:
                rows.append([float(m.group(2)), float(m.group(1)), float(m.group(3))])
        out[r] = rows
    return out


def own_figures(boot: dict[str, float], measured: dict[str, list[list[float]]], wall: float) -> dict[str, float]:
    """robot -> its own figure at Unix time ``wall``: that of its latest
    measurement on the grid by then (``measurements``), else its boot figure."""
    out = {}
    for r, figure in boot.items():
        for moment, _one, node_figure in measured.get(r, []):
            if moment <= wall:
                figure = node_figure
        out[r] = figure
    return out


def boot_speeds(log_dir, names: list[str]) -> dict[str, float]:
    """robot -> the speed its node printed when it joined (0.0 if none yet)."""
    out = {}
    for r in names:
        try:
            text = (log_dir / f"{r}.log").read_text(errors="replace")
        except OSError:
            text = ""
        m = _JOINED.search(text)
        out[r] = float(m.group(1)) if m else 0.0
    return out


def run_speeds(*, starts: int = 10, robots: int = 5, cores: int = 4, quota: float = 0.32, loaded: int = 0,
               log: Callable[[str], None] | None = None) -> SpeedsReport:
    """``starts`` fresh testbeds of ``robots`` identical robots (see the module docstring)."""
    from ramps.testbed import Testbed
    from ramps.testbed.bed import watch_team

    log = log or (lambda _m: None)
    names = [f"r{i}" for i in range(1, robots + 1)]
    out = []
    for i in range(starts):
        with Testbed(names, cores=cores, quota=quota, loaded={r: loaded for r in names} if loaded else None) as tb:
            tb.up()
            up = time.monotonic()
            boot = boot_speeds(tb.log_dir, names)
            up_wall = time.time()
            reported: dict[str, dict[str, float]] = {}
            with watch_team(tb) as obs:
                for at in READ_AT:
                    time.sleep(max(0.0, up + at - time.monotonic()))
                    reported[str(at)] = reported_speeds(obs, robots, timeout=0.0)
            measured = measurements(tb.log_dir, names)
        own = {str(at): own_figures(boot, measured, up_wall + at) for at in READ_AT}
        start = SpeedStart(boot=boot, reported=reported, own=own, measured=measured)
        out.append(start)
        log(f"start {i + 1}/{starts}: boot spread {spread(boot):.3f}, "
            f"+{READ_AT[-1]:g} s {spread(reported[str(READ_AT[-1])]):.3f}")
    return SpeedsReport(robots=robots, cores=cores, quota=quota, loaded=loaded, starts=out)
