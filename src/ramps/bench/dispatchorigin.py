"""What an origin's node spends on each program its client submits, per program.

``python -m ramps.bench.dispatchorigin [--programs 5000] [--batch 1]
[--rounds 3] [--no-record]``

How this works: two real ``NodeRuntime``s (driver, core, the real clock) on
the in-process memory bus, with the memory worker pool
(``ramps.testing.memory``): the origin ``o``, with its durable record
(``--no-record``: none), and a teammate ``h``. Their rounds are run by hand
as their driver threads run them (``NodeRuntime._round``, each with items
queued). Each program is a client's submission of ``noop`` placed round
robin, so every other one runs on ``h``: for it the origin gets the
submission, a round (placed, offered, its record written); the host's
acceptance, a round; the host's result, a round (the record, the outcome,
the acknowledgement). One that runs on ``o`` itself takes a round for the
submission and one for its end. ``--batch`` submissions come in one round (a
burst; 1: calls one after another). The figure is the CPU the stepping
thread spent in the origin's rounds per program (``time.thread_time``),
best of ``--rounds``: its intake, its core, its record and its outputs, and
the memory bus and pool, which stand in for Zenoh and the worker processes
(cheaper than they are). It follows the code, not the machine's load, so
two codes compare on a shared machine; it asserts nothing.
"""

from __future__ import annotations

import argparse
import gc
import shutil
import tempfile
import time
from typing import Any

TEAM = "bench"


def _runtime(bus: Any, robot: str, state: str, pools: dict[str, Any]) -> Any:
    from ramps.runtime.node import NodeRuntime
    from ramps.runtime.settings import load_settings
    from ramps.runtime.transport import REAL_CLOCK
    from ramps.testing.memory import MemoryPool, StillSampler

    def pool(*a: Any, **kw: Any) -> MemoryPool:
        pools[robot] = MemoryPool(*a, **kw)
        return pools[robot]

    flags = {"robot": robot, "team": TEAM, "cores": 2, "speed": 1.0, "battery_sysfs": False, "state_dir": state}
    return NodeRuntime(load_settings(flags=flags, environ={}), transport=bus.transport(robot), clock=REAL_CLOCK,
                       worker_pool=pool, load_sampler=StillSampler, incarnation=1 if robot == "o" else 2)


def _round(rt: Any) -> None:
    """A round of ``rt``'s driver if something is queued for it (else it would wait)."""
    if not rt._q.empty():
        rt._round(block=True)


def origin_cpu(programs: int = 5000, batch: int = 1, rounds: int = 3, record: bool = True) -> list[float]:
    """CPU microseconds per program of each round (see the module docstring)."""
    from ramps.core.messages import SubmitProgram, encode
    from ramps.runtime import keys
    from ramps.runtime.registry import encode_args, default_registry
    from ramps.testing.memory import MemoryBus

    state = tempfile.mkdtemp(prefix="ramps-dispatchorigin-")
    bus = MemoryBus()
    pools: dict[str, Any] = {}
    o = _runtime(bus, "o", state if record else "off", pools)
    h = _runtime(bus, "h", "off", pools)
    got: list[bytes] = []
    bus.transport("c").subscribe(keys.client(TEAM, "c"), got.append)  # the client, reachable
    o.start(threaded=False)
    h.start(threaded=False)
    args = encode_args(default_registry.get("noop"), {})
    out: list[float] = []
    try:
        t_end = time.monotonic() + 1.0
        while time.monotonic() < t_end:  # each hears the other's load report
            o.step(), h.step()
            time.sleep(0.01)
        gc.collect()
        rid = 0
        for _ in range(rounds):
            cpu = 0.0
            for i in range(0, programs, batch):
                subs = []
                for _ in range(min(batch, programs - i)):
                    rid += 1
                    subs.append(encode("c", SubmitProgram(client="c", request_id=rid, program="noop", args=args,
                                                          policy="round_robin")))
                t0 = time.thread_time()
                for data in subs:
                    o._on_wire(data)
                o._round(block=True)  # placed: offered to h, or started here
                cpu += time.thread_time() - t0
                _round(h)  # the offers taken, accepted
                t0 = time.thread_time()
                _round(o)  # the acceptances
                cpu += time.thread_time() - t0
                pools["h"].complete()
                _round(h)  # the results sent
                pools["o"].complete()
                t0 = time.thread_time()
                _round(o)  # the results and local ends: delivered
                cpu += time.thread_time() - t0
                _round(h)  # the acknowledgements
            out.append(cpu / programs * 1e6)
        if len(got) < rounds * programs:
            raise RuntimeError(f"only {len(got)} outcomes of {rounds * programs} programs reached the client")
    finally:
        o.stop()
        h.stop()
        shutil.rmtree(state, ignore_errors=True)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(prog="python -m ramps.bench.dispatchorigin", description=__doc__.splitlines()[0])
    ap.add_argument("--programs", type=int, default=5000, help="programs each round")
    ap.add_argument("--batch", type=int, default=1, help="submissions in one round of the origin's driver")
    ap.add_argument("--rounds", type=int, default=3, help="rounds (the best is the figure)")
    ap.add_argument("--no-record", action="store_true", help="the origin keeps no durable record")
    a = ap.parse_args()
    got = origin_cpu(a.programs, a.batch, a.rounds, record=not a.no_record)
    print(f"origin node, {a.batch} a round{'' if not a.no_record else ', no record'}: CPU per program "
          f"{min(got):.2f} us (rounds: {', '.join(f'{x:.2f}' for x in got)})")


if __name__ == "__main__":
    main()
