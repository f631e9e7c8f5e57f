"""25 nodes, a fifth SIGKILLed during a burst: who is not heard, and why, second by second
(docs/lab/2026-11-27-footprint.md). As root, in a network namespace of its own:
ip netns exec NS .venv/bin/python docs/lab/2026-11-27-footprint-killdiag.py 25 SEED"""
import os, random, sys, time, uuid
from ramps.testing import LocalTeam
from ramps.bench.teamsize import ORIGINS, run_burst, hears

n = int(sys.argv[1])
team = LocalTeam(n, cores=1, visible_timeout=120, team=f"kd-{uuid.uuid4().hex[:6]}")
try:
    team.start()
    time.sleep(2)
    clients = {o: team.client(o) for o in ORIGINS}
    first = clients["r1"]
    run_burst(clients, 2 * n, 0.05, 120)
    victims = random.Random(int(sys.argv[2])).sample([r for r in team.names if r not in ORIGINS], n // 5)
    survivors = set(team.names) - set(victims)
    futs = [clients[ORIGINS[i % 3]].submit("burn", units=0.05) for i in range(2 * n)]
    time.sleep(0.5)
    t0 = time.monotonic()
    for v in victims:
        team.kill_node(v)
    heard = None
    while time.monotonic() - t0 < 20:
        rows = {r.robot: r for r in first.status().robots}
        bad = {s: (None if s not in rows else (rows[s].alive, rows[s].sees, rows[s].report_age and round(rows[s].report_age, 1)))
               for s in sorted(survivors) if not (s in rows and rows[s].alive and rows[s].sees == len(survivors) - 1
                                                  and rows[s].report_age is not None and rows[s].report_age <= 3.0)}
        el = round(time.monotonic() - t0, 1)
        if bad:
            print(el, len(bad), dict(list(bad.items())[:6]), flush=True)
        elif heard is None:
            heard = el
            print(el, "all heard", flush=True)
            break
        time.sleep(0.5)
    print("victims", victims, "heard", heard, "load", os.getloadavg()[0], flush=True)
    for f in futs:
        try:
            f.result(timeout=60)
        except Exception as e:
            print("lost", type(e).__name__)
finally:
    team.close()
