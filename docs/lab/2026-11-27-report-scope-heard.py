"""Messages a second an idle robot's node hears, against the team's size, on the memory bus.

Real nodes (real driver, real core) on ``ramps.testing.memory``'s bus and fake clock; one
application connected to r1 (the one origin); after the join-time reports have aged out,
over 20 fake seconds: what each node's transport heard (samples and query replies), by key
kind. Run: ``.venv/bin/python docs/lab/2026-11-27-report-scope-heard.py 10 50 100``
(100 robots take about 1.5 minutes of one core). With ``PYTHONPATH`` at the code before the
change (whose bus counts nothing), the deliveries are counted here the same way.
"""

import sys
import time

from collections import Counter
from typing import Any

from ramps.core.config import RampsConfig
from ramps.testing import memory
from ramps.testing.memory import MemoryTeam

if not hasattr(memory.MemoryTransport(memory.MemoryBus(), "x"), "heard"):  # the code before: count here
    init = memory.MemoryTransport.__init__

    def counting_init(self: Any, *a: Any) -> None:
        init(self, *a)
        self.heard = Counter()

    def counting_put(self: Any, src: Any, key: str, data: bytes) -> None:
        for t, expr, cb in list(self._subs):
            if memory.intersects(expr, key) and self.reaches(src, t):
                t.heard[key] += 1
                cb(bytes(data))

    memory.MemoryTransport.__init__ = counting_init  # type: ignore[method-assign]
    memory.MemoryBus.put = counting_put  # type: ignore[method-assign]

IDLE = RampsConfig().max_report_age + 5.0

for n in [int(a) for a in sys.argv[1:]] or [10, 50]:
    t0 = time.monotonic()
    team = MemoryTeam({f"r{i}": (4, 4.0) for i in range(1, n + 1)})
    app = team.connect("r1")
    team.run(IDLE)
    before = {name: dict(t.heard) for name, t in team.bus.transports.items()}
    team.run(20.0)

    def rate(name: str) -> float:
        t = team.bus.transports[name]
        return sum(v - before[name].get(k, 0) for k, v in t.heard.items()) / 20.0

    idle = sorted(rate(f"r{i}") for i in range(2, n + 1))
    kinds: dict[str, float] = {}
    for k, v in team.bus.transports["r2"].heard.items():
        if v - before["r2"].get(k, 0):
            part = k.split("/")[2]
            kind = ("load/*/now" if k.endswith("/now") else "load/r2 (its own)" if k.endswith("/load/r2")
                    else "load/* (teammates')" if part == "load" else part)
            kinds[kind] = kinds.get(kind, 0.0) + (v - before["r2"].get(k, 0)) / 20.0
    print(f"{n} robots: an idle robot hears {idle[len(idle) // 2]:.2f}/s (most {idle[-1]:.2f}), r2 by key {kinds}; "
          f"the origin r1 {rate('r1'):.2f}/s ({time.monotonic() - t0:.0f} s wall)", flush=True)
    app.close()
    team.close()
