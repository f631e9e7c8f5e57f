"""What a host's node spends on the programs it runs for a teammate, per program.

``python -m ramps.bench.dispatchhost [--programs 10000] [--batch 1]
[--rounds 3]``

How this works: one real ``NodeRuntime`` (driver, core, durable record,
the real clock) on the in-process memory bus, with the memory worker pool
(``ramps.testing.memory``), its rounds run by hand as its driver thread
runs them (``NodeRuntime._round``, each with items queued): for each
program the bytes of an origin's offer reach it, a round, the program's
end, a round, the origin's acknowledgement, a round. ``--batch`` programs go each way in one
round (a burst; 1: calls one after another, each in rounds of its own).
The figure is the CPU the stepping thread spent per program
(``time.thread_time``), best of ``--rounds``: the driver's rounds, its
intake, the core and its outputs, and the memory bus and pool, which stand
in for Zenoh and the worker processes (cheaper than they are). It follows
the code, not the machine's load, so two codes compare on a shared
machine; it asserts nothing.
"""

from __future__ import annotations

import argparse
import gc
import shutil
import tempfile
import time
from typing import Any


def host_cpu(programs: int = 10_000, batch: int = 1, rounds: int = 3) -> list[float]:
    """CPU microseconds per program of each round (see the module docstring)."""
    from ramps.core.messages import OffloadRequest, ResultAck, encode
    from ramps.runtime.node import NodeRuntime
    from ramps.runtime.settings import load_settings
    from ramps.runtime.transport import REAL_CLOCK
    from ramps.testing.memory import MemoryBus, MemoryPool, StillSampler

    state = tempfile.mkdtemp(prefix="ramps-dispatchhost-")
    pools: list[MemoryPool] = []

    def pool(*a: Any, **kw: Any) -> MemoryPool:
        pools.append(MemoryPool(*a, **kw))
        return pools[-1]

    flags = {"robot": "h", "team": "bench", "cores": 2, "speed": 1.0, "battery_sysfs": False, "state_dir": state}
    rt = NodeRuntime(load_settings(flags=flags, environ={}), transport=MemoryBus().transport("h"), clock=REAL_CLOCK,
                     worker_pool=pool, load_sampler=StillSampler, incarnation=1)
    rt.start(threaded=False)
    gc.collect()
    out: list[float] = []
    try:
        for r in range(rounds):
            ids = [f"p{r}-{i}" for i in range(programs)]
            offers = [encode("o", OffloadRequest(program_id=p, attempt=1, origin="o", host="h", program="noop",
                                                 work=0.001)) for p in ids]
            acks = [encode("o", ResultAck(program_id=p, attempt=1, origin="o")) for p in ids]
            t0 = time.thread_time()
            for i in range(0, programs, batch):
                for data in offers[i:i + batch]:
                    rt._on_wire(data)
                rt._round(block=True)  # something is queued: it does not wait
                pools[0].complete()
                rt._round(block=True)
                for data in acks[i:i + batch]:
                    rt._on_wire(data)
                rt._round(block=True)
            out.append((time.thread_time() - t0) / programs * 1e6)
    finally:
        rt.stop()
        shutil.rmtree(state, ignore_errors=True)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(prog="python -m ramps.bench.dispatchhost", description=__doc__.splitlines()[0])
    ap.add_argument("--programs", type=int, default=10_000, help="programs each round")
    ap.add_argument("--batch", type=int, default=1, help="programs each way in one round of the driver")
    ap.add_argument("--rounds", type=int, default=3, help="rounds (the best is the figure)")
    a = ap.parse_args()
    got = host_cpu(a.programs, a.batch, a.rounds)
    print(f"host node, {a.batch} a round: CPU per program {min(got):.2f} us "
          f"(rounds: {', '.join(f'{x:.2f}' for x in got)})")


if __name__ == "__main__":
    main()
