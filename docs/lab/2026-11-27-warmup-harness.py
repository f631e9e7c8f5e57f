"""Issue 28's warm-up case on the testbed: an application warms the team up
with 20 calls of ``burn`` that do 0.002 units each while declaring 1.5, then
submits 30 real calls of 1.5 units declaring the same. Prints the real
calls' makespan beside the ideal (30 programs of 1.5 units on five robots of
4 emulated cores, processor sharing: 6 a robot) at the speed measured before
the run and at what a work unit cost the robots' cgroups during it (the
host's true speed then), their distribution, the
origin's mis-declaration notes and metric, and the robots' speeds after the
run (as they report them, and as the origin corrects them from results).

Run as root from the repository: ``.venv/bin/python docs/lab/2026-11-27-warmup-harness.py``.
"""

from __future__ import annotations

import json
import time
from collections import Counter
from pathlib import Path

from ramps.testbed import Testbed
from ramps.testbed.bed import watch_team
from ramps.lab.experiments import identical_speed

NAMES = [f"r{i}" for i in range(1, 6)]
CORES, QUOTA, WORK = 4, 0.32, 1.5

speed = identical_speed(1, CORES, QUOTA)
with Testbed(NAMES, cores=CORES, quota=QUOTA) as tb:
    tb.up()
    with tb.client("r1", timeout=30.0) as team:
        t = time.monotonic()
        warm = [team.options(work=WORK).submit("burn", units=0.002) for _ in range(20)]
        for f in warm:
            f.result(timeout=120)
        warm_s = time.monotonic() - t
        acct = [Path(f"/sys/fs/cgroup/cpuacct/ramps-{tb.tb}-{r}/cpuacct.usage") for r in NAMES]
        used0 = sum(int(a.read_text()) for a in acct) / 1e9
        t = time.monotonic()
        real = [team.options(work=WORK).submit("burn", units=WORK) for _ in range(30)]
        for f in real:
            f.result(timeout=600)
        span = time.monotonic() - t
        used = sum(int(a.read_text()) for a in acct) / 1e9 - used0
        hosts = Counter(f.host for f in real)
    with watch_team(tb) as obs:
        time.sleep(2.5)
        reports = {r: rep for r, (rep, _) in obs.reports.items()}
    trace = (tb.log_dir / "r1.trace.jsonl").read_text().splitlines()
    misdeclared = [json.loads(x) for x in trace if '"misdeclared"' in x]
ideal = WORK / (speed * CORES * len(NAMES) / 30)
true_speed = 30 * WORK / used * QUOTA / CORES  # units a second of an emulated core, during the run
true_ideal = WORK / (true_speed * CORES * len(NAMES) / 30)
reported = {r: reports[r].speed for r in NAMES if r in reports}
factors = {link.robot: link.speed_factor for link in reports["r1"].links} if "r1" in reports else {}
print(f"host speed before: {speed:.4f} units/s of an emulated core; warm-up of 20 calls: {warm_s:.1f} s")
print(f"30 real calls: {span:.1f} s, ideal {ideal:.1f} s (ratio {span / ideal:.3f}); "
      f"distribution {'-'.join(str(hosts.get(r, 0)) for r in NAMES)}; a unit cost {used / 30 / WORK:.2f} CPU s "
      f"(before: {QUOTA / CORES / speed:.2f}): ideal at that speed {true_ideal:.1f} s, ratio {span / true_ideal:.3f}")
print(f"mis-declaration notes at the origin: {len(misdeclared)}; first: "
      f"{misdeclared[0]['detail'] if misdeclared else '-'}")
print(f"speeds reported: {reported} (spread {max(reported.values()) / min(reported.values()):.3f}); "
      f"r1's corrections from results: {factors}")
