"""Lab harness of docs/lab/2026-11-27-fastest-pieces.md (cgroup v1, root).

Five cpu cgroups of 0.32 host cores, each with a measuring process at nice -5
(a node's priority) and optionally LOADED busy processes; every 3 s, on one
wall-clock grid, each measuring process times ``chunk_rates(0.2)`` and keeps
the raw pieces, so any statistic can be compared on the same pieces:

    python 2026-11-27-fastest-pieces-harness.py ROBOTS MOMENTS LOADED OUT_PREFIX

writes OUT_PREFIX.r<i>.json: [{"at", "wall", "pieces": {cpu: [rates]}}, ...].
"""

import os
import subprocess
import sys
import time

robots, moments, loaded, out = int(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
root = "/sys/fs/cgroup/cpu/lab_fastest_pieces"
os.makedirs(root, exist_ok=True)
start = time.time() + 3
measuring, busy = [], []
for i in range(robots):
    d = f"{root}/r{i}"
    os.makedirs(d, exist_ok=True)
    open(f"{d}/cpu.cfs_period_us", "w").write("100000")
    open(f"{d}/cpu.cfs_quota_us", "w").write("32000")
    code = f"""
import json, os, time
open('{d}/cgroup.procs', 'w').write(str(os.getpid()))
os.nice(-5)
from ramps.runtime.speed_probe import chunk_rates
res = []
for m in range({moments}):
    at = {start} + 3 * m
    time.sleep(max(0, at - time.time()))
    w = time.time()
    p = chunk_rates(0.2)
    res.append(dict(at=at, wall=time.time() - w, pieces={{str(k): v for k, v in p.items()}}))
json.dump(res, open('{out}.r{i}.json', 'w'))
"""
    measuring.append(subprocess.Popen([sys.executable, "-c", code]))
    for _ in range(loaded):
        busy.append(subprocess.Popen(["sh", "-c", f"echo $$ > {d}/cgroup.procs; exec python3 -c 'while True: pass'"]))
for p in measuring:
    p.wait()
for p in busy:
    p.kill()
    p.wait()
time.sleep(0.5)
for i in range(robots):
    os.rmdir(f"{root}/r{i}")
os.rmdir(root)
