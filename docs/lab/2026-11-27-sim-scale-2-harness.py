"""One ``large_team`` run (docs/lab/2026-11-27-sim-scale-2.md): its figures
as a JSON line on stdout, a progress line every 250,000 events on stderr.

    nice -n 15 .venv/bin/python THIS ROBOTS PROGRAMS ORIGINS LABEL [UNTIL]

UNTIL: stop at that virtual second and print what was done by then.
FANOUT=n in the environment: the team sets ``report_fanout`` n. Another
commit: ``PYTHONPATH=<its worktree>/src``.
"""
import collections, heapq, json, os, sys, time
from ramps.bench.simulator import large_team
from ramps.sim.engine import Simulator
n, m, k = (int(x) for x in sys.argv[1:4])
code = sys.argv[4] if len(sys.argv) > 4 else "?"
until = float(sys.argv[5]) if len(sys.argv) > 5 else float("inf")
sc = large_team(n, m, k)
if os.environ.get("FANOUT"):  # a team that sets report_fanout (ramps.core.fanout)
    import msgspec
    sc = msgspec.structs.replace(sc, config=msgspec.structs.replace(sc.config, report_fanout=int(os.environ["FANOUT"])))
load0 = os.getloadavg()
t0 = time.perf_counter(); c0 = time.process_time()
sim = Simulator(sc)
sim._setup()
heap = sim._heap
next_log = 0
while heap and sim._pending > 0:
    t, _, fn, arg = heapq.heappop(heap)
    if t > until:
        print(json.dumps({"code": code, "robots": n, "programs": m, "origins": k, "until": until, "events": sim.events,
                          "sent": sim.sent, "wall": round(time.perf_counter() - t0, 2),
                          "cpu": round(time.process_time() - c0, 2), "pending": sim._pending,
                          "delivered": m - sim._pending, "load_before": [round(x, 2) for x in load0],
                          "load_after": [round(x, 2) for x in os.getloadavg()]}), flush=True)
        sys.exit(0)
    sim.now = t
    sim.events += 1
    fn(arg)
    if sim.events >= next_log:
        next_log += 250_000
        print(json.dumps({"events": sim.events, "virtual": round(t, 1), "wall": round(time.perf_counter() - t0, 1),
                          "cpu": round(time.process_time() - c0, 1), "pending": sim._pending,
                          "load": os.getloadavg()[0]}), file=sys.stderr, flush=True)
wall = time.perf_counter() - t0; cpu = time.process_time() - c0
res = sim._result(wall)
bound = m * 53.0 / (4 * n)
last = max(p.submitted_at for p in res.programs) - min(p.submitted_at for p in res.programs)
lb = max(bound, last + 53.0)
hist = collections.Counter(res.distribution.values())
print(json.dumps({"code": code, "robots": n, "programs": m, "origins": k, "wall": round(wall, 2), "cpu": round(cpu, 2),
                  "events": res.events, "sent": res.messages_sent, "makespan": round(res.makespan, 2),
                  "bound": bound, "ratio": round(res.makespan / bound, 4), "lower_bound": round(lb, 2),
                  "ratio_lb": round(res.makespan / lb, 4), "completed": res.completed, "lost": res.lost,
                  "dup": res.duplicated, "hist": {str(a): b for a, b in sorted(hist.items())},
                  "rej": sum(s.rejections for s in res.statistics), "moves": sum(s.moves for s in res.statistics),
                  "load_before": [round(x, 2) for x in load0], "load_after": [round(x, 2) for x in os.getloadavg()]}),
      flush=True)
