"""T_comm on a slow link, on the testbed: measured per teammate, and placement avoids it.

How this works: three robots (r1 places, r2 and r3 are idle and identical).
One
robot's link (``r3``) is slowed to ``rate`` bytes/s in both directions
(``ramps.testbed.slowlink.slow_link``: a token-bucket filter on both ends of
its veth).

r1 measures its links while idle (until it has a bandwidth figure for both
teammates), then ``stress`` busy processes start on r1, so its programs go
to a teammate, and r1 submits ``programs`` programs one after another (each waits for the
previous result, so r2 and r3 are equally idle at every decision), each
carrying ``payload`` bytes of parameters (``crunch``: burn ``units``, return
the size). The run is done twice on fresh testbeds: with every link at full
speed (r2 and r3 tie, so programs go to either), then with r3's link slowed:
r1's measured link to r3 (``LoadReport.links``, the same figures ``ramps
status`` shows) converges towards the shaped rate, and the programs avoid r3.

Run ``ramps testbed experiment slow-link`` (root; about 4 minutes).
"""

from __future__ import annotations

import shutil
import time
from collections.abc import Callable
from pathlib import Path

import msgspec

from ramps.testbed.slowlink import TARGET, slow_link


class LinkSample(msgspec.Struct, kw_only=True):
    #: seconds since the link was slowed; r1's estimate of its link to the robot
    t: float
    latency: float | None
    bandwidth: float | None


class SlowLinkRun(msgspec.Struct, kw_only=True):
    shaped: bool
    #: programs per robot (r1, r2, r3) and the seconds from submit to result of each
    distribution: list[int]
    durations: list[float]
    #: r1's measured links to r2 and r3 when the programs were submitted
    links: dict[str, list[float | None]]
    #: r1's estimate of the slowed robot's link over time (shaped runs only)
    convergence: list[LinkSample] = []
    #: at each submission (while r1 is loaded): r1's measured links to r2 and r3, and
    #: r2's and r3's to r1 ("r2>r1"), as [latency, bandwidth]; and r1's node's cores
    at_placement: list[dict[str, list[float | None]]] = []
    node_cpu: list[float | None] = []


class SlowLinkReport(msgspec.Struct, kw_only=True):
    __test__ = False
    rate: float
    payload: int
    units: float
    slow: str
    runs: list[SlowLinkRun]


def _links(obs, robots: list[str], of: str = "r1") -> dict[str, list[float | None]]:
    rep = obs.report(of)
    seen = {link.robot: [link.latency, link.bandwidth] for link in (rep.links if rep else [])}
    return {r: seen.get(r, [None, None]) for r in robots}


def _both_ways(obs) -> dict[str, list[float | None]]:
    """r1's links to r2 and r3, and theirs to r1 (keys "r2>r1", "r3>r1")."""
    out = _links(obs, ["r2", "r3"])
    for r in ("r2", "r3"):
        out[f"{r}>r1"] = _links(obs, ["r1"], of=r)["r1"]
    return out


def run_once(*, shaped: bool, slow: str = "r3", rate: float = 1e6, payload: int = 1_000_000, units: float = 0.3,
             programs: int = 6, stress: int = 8, quota: float = 0.3, converge: float = 60.0,
             log: Callable[[str], None] | None = None, keep_logs: Path | None = None,
             told_speed: bool = False) -> SlowLinkRun:
    from ramps.testbed import Testbed
    from ramps.testbed.bed import watch_team
    from ramps.lab.experiments import SETTLE, identical_speed

    log = log or (lambda _m: None)
    speed = identical_speed(1, 4, quota)
    names = ["r1", "r2", "r3"]
    with Testbed(names, cores=4, quota=quota, speed=speed if told_speed else None, programs=[TARGET]) as tb, \
            watch_team(tb) as obs, tb.client("r1", timeout=60.0) as team:
        t0 = time.monotonic()
        convergence: list[LinkSample] = []
        if shaped:
            slow_link(tb, slow, rate)
            log(f"  {slow}'s link slowed to {rate / 1e6:g} MB/s (tbf, both directions)")
        # r1's estimates while it is idle: a robot whose CPU budget is spent (its cgroup
        # throttled) answers probes late, and every link then reads the same: measured,
        # 9.6 ms and 0.31 MB/s to both r2 and r3 with r1's cores full, 64 ms and 0.042 MB/s
        # next to 8 busy processes, while r3 alone was slowed to 1 MB/s
        deadline = t0 + converge
        while time.monotonic() < deadline:
            lat, bw = _links(obs, [slow])[slow]
            convergence.append(LinkSample(t=round(time.monotonic() - t0, 1), latency=lat, bandwidth=bw))
            if all(v[1] is not None for v in _links(obs, ["r2", "r3"]).values()):
                break
            time.sleep(1.0)
        log(f"  r1's estimate of {slow}'s link after {time.monotonic() - t0:.0f} s: "
            f"latency {_fmt(convergence[-1].latency, 1e3, 'ms')}, "
            f"bandwidth {_fmt(convergence[-1].bandwidth, 1e-6, 'MB/s')}")
        links = _links(obs, ["r2", "r3"])
        tb.add_load("r1", stress)  # now r1 is busy: its programs go to a teammate
        time.sleep(SETTLE)
        data = b"\x5a" * payload
        hosts, durations = [], []
        at_placement: list[dict[str, list[float | None]]] = []
        node_cpu: list[float | None] = []
        for i in range(programs):
            at_placement.append(_both_ways(obs))
            rep = obs.report("r1")
            node_cpu.append(rep.node_cpu if rep is not None else None)
            t = time.monotonic()
            fut = team.options(work=units).submit("crunch", data=data, units=units)
            res = fut.result(timeout=300)
            if res.get("bytes") != payload:
                raise RuntimeError(f"crunch returned {res!r}")
            hosts.append(fut.host)
            durations.append(round(time.monotonic() - t, 2))
            lk = at_placement[-1]
            log(f"  program {i + 1}: {fut.host} in {durations[-1]:.1f} s; r1 measured r2 "
                f"{_fmt(lk['r2'][1], 1e-6, 'MB/s')}, r3 {_fmt(lk['r3'][1], 1e-6, 'MB/s')} "
                f"(r3 measured r1 {_fmt(lk['r3>r1'][1], 1e-6, 'MB/s')})")
        if keep_logs is not None and tb.log_dir is not None:  # the nodes' logs and traces outlive the testbed
            dest = keep_logs / ("shaped" if shaped else "full-speed")
            shutil.copytree(tb.log_dir, dest, dirs_exist_ok=True)
            log(f"  logs and traces kept in {dest}")
    return SlowLinkRun(shaped=shaped, distribution=[hosts.count(r) for r in names], durations=durations,
                       links=links, convergence=convergence, at_placement=at_placement, node_cpu=node_cpu)


def _fmt(x: float | None, scale: float, unit: str) -> str:
    return "not measured" if x is None else f"{x * scale:.3g} {unit}"


def run_slow_link(*, rate: float = 1e6, payload: int = 1_000_000, units: float = 0.3, programs: int = 6,
                  log: Callable[[str], None] | None = None, keep_logs: Path | None = None,
                  told_speed: bool = False) -> SlowLinkReport:
    log = log or (lambda _m: None)
    runs = []
    for shaped in (False, True):
        log(f"{'r3 slowed' if shaped else 'every link at full speed'}: {programs} programs of {payload} bytes")
        runs.append(run_once(shaped=shaped, rate=rate, payload=payload, units=units, programs=programs, log=log,
                             keep_logs=keep_logs, told_speed=told_speed))
    return SlowLinkReport(rate=rate, payload=payload, units=units, slow="r3", runs=runs)


def format_report(rep: SlowLinkReport) -> str:
    lines = [f"r1 (loaded) places {len(rep.runs[0].durations)} programs of {rep.payload / 1e6:g} MB parameters "
             f"and {rep.units:g} units, one after another, on idle r2 and r3; r3's link slowed to "
             f"{rep.rate / 1e6:g} MB/s (tbf) in the second run"]
    for run in rep.runs:
        lk = "; ".join(f"{r}: {_fmt(v[0], 1e3, 'ms')}, {_fmt(v[1], 1e-6, 'MB/s')}" for r, v in run.links.items())
        lines.append(f"{'r3 slowed' if run.shaped else 'full speed'}: r1-r2-r3 {'-'.join(map(str, run.distribution))}"
                     f", median {sorted(run.durations)[len(run.durations) // 2]:.1f} s a program; r1 measured {lk}")
        if run.convergence:
            lines.append("  r1's estimate of r3's bandwidth after the slowdown: " + ", ".join(
                f"{s.t:g} s {_fmt(s.bandwidth, 1e-6, 'MB/s')}" for s in run.convergence[:: max(1, len(
                    run.convergence) // 8)] + run.convergence[-1:]))
    return "\n".join(lines)
