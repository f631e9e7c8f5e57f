"""The demo's phases in a given order on one team (docs/lab/2026-11-27-after-selfcount.md).

Usage: python docs/lab/2026-11-27-demo-order.py rr,ramps,rr,ramps NAME
(root for the cgroups; writes /tmp/demo23/order-NAME.json and the nodes' trace beside it)."""
import json
import os
import sys
import time
from ramps.bench.demo import route_calls, _run_phase, _emulation, DEMO_ROUTE
from ramps.testing import LocalTeam
order = sys.argv[1].split(",")
trace = "/tmp/demo23/trace-%s.jsonl" % sys.argv[2]
os.makedirs("/tmp/demo23", exist_ok=True)
open(trace, "w").close()
host_cores, quota, mode = _emulation(5, None)
calls = route_calls(dict(DEMO_ROUTE), 15)
names = [f"r{i}" for i in range(1, 6)]
out = []
with LocalTeam(names, cpu_quota=quota, env=dict(os.environ, RAMPS_TRACE=trace)) as team:
    client = team.client("r1")
    time.sleep(2.5)
    warm = [client.options(policy="round_robin").submit("route_plan", **c) for c in calls[:5]]
    for f in warm:
        f.result(timeout=120)
    for title in order:
        opts = {} if title == "ramps" else {"policy": "round_robin"}
        w0 = time.time()
        p = _run_phase(title, client, calls, program="route_plan", options=opts, on_progress=None)
        out.append(dict(name=title, makespan=round(p.makespan, 2), dist=p.distribution, t0=w0, t1=time.time(),
                        load=os.getloadavg()[0]))
        print(out[-1], flush=True)
    client.close()
json.dump(out, open("/tmp/demo23/order-%s.json" % sys.argv[2], "w"))
