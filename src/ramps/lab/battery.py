"""A robot's battery drops below its reserve mid-run, on real processes:
``ramps testbed experiment battery``.

How this works: a fresh testbed of ``robots`` emulated robots whose nodes
read their battery from a file each (``battery_file`` with ``{robot}``,
all at 90%). r1 submits ``programs`` ``burn`` programs of ``seconds``
seconds each (alone on an emulated core), saving their place every
``checkpoint_every`` seconds; ``drop_at`` seconds after the first, the
teammate that hosts the most of them gets 10% written into its battery
file. Its node reads the file before its next load report (every
``publish_period``, 1 s) and hands back what it runs for r1, whose origin
places each program elsewhere at once, resuming from its checkpoint.

Measured, all from the same monotonic clock (the nodes' decision traces
carry ``time.monotonic()``): the shed time, from the write to the low
robot's ``battery_low`` decision; the re-placement time, from the write to
the last of the handed-back programs accepted elsewhere; the makespan; and
every program's one result, checked against an uninterrupted burn's
checksum (nothing lost, nothing run twice to a different end).
"""

from __future__ import annotations

import shutil
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import msgspec

SPACING = 0.05


class BatteryShed(msgspec.Struct, kw_only=True):
    robots: int
    cores: int
    quota: float
    programs: int
    seconds: float
    drop_at: float
    publish_period: float
    #: the robot whose battery dropped, and the programs it hosted for r1 then
    low: str
    hosted: list[str]
    #: seconds from the file's write to the low robot's decision, and to the
    #: last handed-back program accepted elsewhere (None: none seen)
    shed_s: float | None
    replaced_s: float | None
    #: handed-back programs that resumed from a checkpoint elsewhere
    resumed: int
    makespan: float
    completed: int
    failed: int
    #: results whose checksum is not an uninterrupted burn's, and programs
    #: delivered from the low robot after the drop (both must be 0)
    wrong: int
    on_low_after: int
    distribution: dict[str, int]
    wall_seconds: float = 0.0


def run_testbed_battery(*, robots: int = 3, cores: int = 2, quota: float = 0.25, programs: int = 6,
                        seconds: float = 12.0, drop_at: float = 4.0, checkpoint_every: float = 1.0,
                        timeout: float = 300.0, keep_logs: Path | None = None,
                        log: Callable[[str], None] | None = None) -> BatteryShed:
    """The experiment (module docstring) on a fresh testbed."""
    from ramps.programs.burn import burn
    from ramps.lab.experiments import identical_speed

    log = log or (lambda _m: None)
    if robots < 2 or programs < 1 or not 0 < drop_at < seconds:
        raise ValueError("need robots >= 2, programs >= 1 and 0 < drop_at < seconds")
    started = time.monotonic()
    speed = identical_speed(1, cores, quota)
    units, every = round(seconds * speed, 4), round(checkpoint_every * speed, 4)
    expected = burn(units=units)["checksum"]
    files = Path(tempfile.mkdtemp(prefix="ramps-battery-"))
    try:
        return _run(files, robots=robots, cores=cores, quota=quota, programs=programs, seconds=seconds,
                    drop_at=drop_at, speed=speed, units=units, every=every, expected=expected, timeout=timeout,
                    keep_logs=keep_logs, log=log, started=started)
    finally:
        shutil.rmtree(files, ignore_errors=True)


def _run(files: Path, *, robots: int, cores: int, quota: float, programs: int, seconds: float, drop_at: float,
         speed: float, units: float, every: float, expected: str, timeout: float, keep_logs: Path | None,
         log: Callable[[str], None], started: float) -> BatteryShed:
    """Long because it is the experiment's one timeline: the testbed up, the burst, the drop, the wait,
    the figures from the traces, all inside the testbed's ``with`` block."""
    from ramps.testbed import Testbed
    from ramps.lab.experiments import _keep, _log_dir, hosts_at, read_trace

    names = [f"r{i}" for i in range(1, robots + 1)]
    for name in names:
        (files / f"battery-{name}").write_text("90\n")
    config = {"battery_file": str(files / "battery-{robot}"), "battery_sysfs": False, "worker_nice": 0}
    log(f"one emulated core runs {speed:.4f} units/s: {programs} programs of {units:g} units ({seconds:g} s alone), "
        f"checkpoints every {every:g} units; batteries read from {files}")
    with Testbed(robots, cores=cores, quota=quota, config=config) as tb:
        team = tb.client("r1", timeout=30.0)
        try:
            t0 = time.monotonic()
            futures: list[Any] = []
            ends: dict[int, float] = {}
            for i in range(programs):
                futures.append(team.options(work=units).submit("burn", units=units, checkpoint_every=every))
                futures[-1].add_done_callback(lambda _f, i=i: ends.setdefault(i, time.monotonic()))
                time.sleep(max(0.0, t0 + (i + 1) * SPACING - time.monotonic()))
            time.sleep(max(0.0, t0 + drop_at - time.monotonic()))
            where = hosts_at(read_trace(_log_dir(tb) / "r1.trace.jsonl"), time.monotonic())
            low = max((n for n in names if n != "r1"), key=lambda n: sum(1 for h in where.values() if h == n))
            hosted = sorted(p for p, h in where.items() if h == low)
            (files / f"battery-{low}").write_text("10\n")
            dropped = time.monotonic()
            log(f"  {dropped - t0:.2f} s: {low}'s battery at 10%, it hosts {len(hosted)} of r1's programs")
            while not all(f.done() for f in futures) and time.monotonic() < t0 + timeout:
                time.sleep(0.2)
            for f in futures:
                if not f.done():
                    f.cancel()
            ok = [f for f in futures if f.done() and not f.cancelled() and f.exception() is None]
            shed, replaced = _shed_times(tb, low, hosted, dropped)
            rep = BatteryShed(
                robots=robots, cores=cores, quota=quota, programs=programs, seconds=seconds, drop_at=drop_at,
                publish_period=1.0, low=low, hosted=hosted,
                shed_s=None if shed is None else round(shed - dropped, 3),
                replaced_s=None if replaced is None else round(replaced - dropped, 3),
                resumed=sum(1 for f in ok if f.resumed_from is not None),
                makespan=round(max(ends.values()) - t0, 2) if len(ends) == programs else float("nan"),
                completed=len(ok), failed=programs - len(ok),
                wrong=sum(1 for f in ok if f.result()["checksum"] != expected),
                on_low_after=sum(1 for i, f in enumerate(futures) if f in ok and f.host == low and ends[i] > dropped),
                distribution={n: sum(1 for f in ok if f.host == n) for n in names},
                wall_seconds=round(time.monotonic() - started, 1))
        finally:
            team.close()
            if keep_logs is not None:
                _keep(tb, Path(keep_logs))
    return rep


def _shed_times(tb: Any, low: str, hosted: list[str], dropped: float) -> tuple[float | None, float | None]:
    """When ``low`` decided it was below its reserve after ``dropped``, and
    when r1 last had one of ``hosted`` accepted by another robot."""
    from ramps.lab.experiments import _log_dir, read_trace

    shed = next((e.t for e in read_trace(_log_dir(tb) / f"{low}.trace.jsonl")
                 if e.what == "battery_low" and e.t >= dropped), None)
    again: dict[str, float] = {}
    for e in read_trace(_log_dir(tb) / "r1.trace.jsonl"):
        if e.what == "accepted" and e.program_id in hosted and e.other != low and e.t >= dropped:
            again.setdefault(e.program_id, e.t)
    return shed, (max(again.values()) if hosted and len(again) == len(hosted) else None)


def format_report(rep: BatteryShed) -> str:
    def s(x: float | None) -> str:
        return "-" if x is None else f"{x:.2f} s"

    return "\n".join([
        f"{rep.robots} robots of {rep.cores} cores on {rep.quota:g} host cores each; r1 submits {rep.programs} "
        f"programs of {rep.seconds:g} s; {rep.drop_at:g} s in, {rep.low}'s battery drops to 10% (reserve 20%) "
        f"while it hosts {len(rep.hosted)} of them; reports every {rep.publish_period:g} s",
        f"shed (file written -> {rep.low} hands back): {s(rep.shed_s)}; re-placed (-> the last accepted "
        f"elsewhere): {s(rep.replaced_s)}; {rep.resumed} resumed from checkpoints",
        f"makespan {rep.makespan:.1f} s; {rep.completed} completed, {rep.failed} failed, {rep.wrong} wrong, "
        f"{rep.on_low_after} on {rep.low} after the drop; where they ended: "
        + ", ".join(f"{k} {v}" for k, v in rep.distribution.items()) + f"; {rep.wall_seconds:.0f} s",
    ])
