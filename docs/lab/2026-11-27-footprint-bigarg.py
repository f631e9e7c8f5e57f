"""Latency of a program with a large argument, client -> node on one host, shared memory on (1) or off (0)
(docs/lab/2026-11-27-footprint.md): .venv/bin/python docs/lab/2026-11-27-footprint-bigarg.py 1"""
import os, statistics, sys, time
os.environ["RAMPS_SHARED_MEMORY"] = sys.argv[1]
from ramps.testing import LocalTeam

def timed(c, prog, size, n):
    arg = "x" * size
    out = []
    for _ in range(n):
        t0 = time.perf_counter()
        c.submit(prog, data=arg).result(timeout=60)
        out.append((time.perf_counter() - t0) * 1000)
    return round(statistics.median(out), 2), round(sorted(out)[int(0.9 * n)], 2)

with LocalTeam(1, cores=1) as team:
    c = team.client("r1")
    timed(c, "noop", 1000, 5)
    res = {f"{p} {s // 1000} kB": timed(c, p, s, 40) for p, s in
           (("noop", 1000), ("noop", 100_000), ("noop", 1_000_000), ("echo", 1_000_000), ("noop", 4_000_000))}
    def shm(pid):
        return sorted({l.split()[-1] for l in open(f"/proc/{pid}/maps") if "/dev/shm/" in l})
    res["client maps"] = len(shm(os.getpid()))
    res["node maps"] = len(shm(team.nodes["r1"].pid))
    print("shm", sys.argv[1], "loadavg", os.getloadavg()[0], res, flush=True)
