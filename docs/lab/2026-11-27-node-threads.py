"""Where an idle node's CPU goes, by thread, in a team of N on loopback
(docs/lab/2026-11-27-team-size.md). Five nodes' threads (r4-r8) read from
/proc over 20 s. Usage, as root, in a network namespace of its own:

    ip netns add thr && ip netns exec thr ip link set lo up
    ip netns exec thr python docs/lab/2026-11-27-node-threads.py 25
    ip netns del thr
"""
import os
import sys
import time
import collections
from ramps.testing import LocalTeam
n = int(sys.argv[1])
def snap(pid):
    out = {}
    for tid in os.listdir(f"/proc/{pid}/task"):
        try:
            data = open(f"/proc/{pid}/task/{tid}/stat").read()
            name = open(f"/proc/{pid}/task/{tid}/comm").read().strip()
        except OSError:
            continue
        f = data[data.rindex(")") + 2:].split()
        out[tid] = (name, (int(f[11]) + int(f[12])) / os.sysconf("SC_CLK_TCK"))
    return out
with LocalTeam(n, cores=1, visible_timeout=120) as team:
    time.sleep(5)
    pids = [team.nodes[f"r{i}"].pid for i in range(4, 9)]
    a = {p: snap(p) for p in pids}
    t0 = time.monotonic()
    time.sleep(20)
    b = {p: snap(p) for p in pids}
    span = time.monotonic() - t0
    agg = collections.Counter()
    for p in pids:
        for tid, (name, cpu) in b[p].items():
            agg[name] += (cpu - a[p].get(tid, (name, 0.0))[1]) / span / len(pids) * 100
    tot = sum(agg.values())
    print(f"{n} nodes: per node {tot:.2f}% of a core, by thread name:")
    for name, v in agg.most_common(12):
        print(f"  {v:6.3f}%  {name}")
