"""What one program costs in CPU, without the network: the core alone, and the
drivers with the core and a client.

``python -m ramps.bench.dispatchcpu [--programs 5000] [--window 256]
[--out FILE.json]``

How this works: both parts are one process on a fake clock, so their figure
is the CPU that process used (``time.process_time``) per program, whatever
else the machine runs; nothing in them sleeps or waits for a network.

* ``core``: three ``ramps.core.node.Node`` objects (2 cores each), one origin,
  ``--programs`` no-ops with ``--window`` in flight; every message and every
  report of the instant (``PublishReport``) is handed to its receivers in
  order, the hosts finish their programs 8 at a time. What the placement,
  the load server and the executor cost.
* ``driver``: ``ramps.testing.memory.MemoryTeam`` (three real ``NodeRuntime``
  drivers, in-process no-op programs, the durable record on in a temporary
  folder) and a real client (``ramps.runtime.client.Team``) on the in-memory
  bus: the same burst, then ``--programs`` / 5 calls one at a time. What the
  core, the drivers (decoding, checks, the durable record, encoding) and
  the client cost together; Zenoh and the worker processes excluded.

``ramps bench dispatch`` measures the real thing (processes, Zenoh, wall
time); this one separates the Python from it. Printed and saved as JSON;
it asserts nothing.
"""

from __future__ import annotations

import argparse
import json
import logging
import random
import shutil
import sys
import tempfile
import time
from collections import Counter, deque
from typing import Any

from ramps.bench.simulator import machine

ROBOTS = ("r1", "r2", "r3")


def core_burst(programs: int = 5000, window: int = 256) -> dict[str, Any]:
    """The core alone: CPU per program of a burst from one origin (see the module's docstring)."""
    from ramps.core.events import Deliver, ProgramFinished, PublishReport, Received, Send, StartProgram, Submit
    from ramps.core.node import Node

    nodes = {name: Node(name, cores=2, speed=1.0, rng=random.Random(i)) for i, name in enumerate(ROBOTS)}
    now = 0.0
    for n in nodes.values():  # every robot has heard every robot once
        rep = n.make_report(cpu_busy=0.0, runnable=0.0, ramps_avg=0.0, window=1.0)
        for m in nodes.values():
            m.handle(Received(sender=n.robot, msg=rep), now)
    inbox: deque[tuple[str, Any]] = deque()
    running: dict[str, deque[tuple[str, int]]] = {name: deque() for name in nodes}
    counts = Counter[str]()

    def handle(robot: str, event: Any) -> None:
        for a in nodes[robot].handle(event, now):
            if isinstance(a, Send):
                inbox.append((a.to, Received(sender=robot, msg=a.msg)))
            elif isinstance(a, StartProgram):
                running[robot].append((a.program_id, a.attempt))
            elif isinstance(a, PublishReport):
                counts["reports"] += 1
                inbox.extend((other, Received(sender=robot, msg=a.report)) for other in nodes if other != robot)
            elif isinstance(a, Deliver):
                counts["delivered"] += 1

    def drain() -> None:
        while inbox:
            handle(*inbox.popleft())

    submitted = 0
    started = time.process_time()
    while counts["delivered"] < programs:
        now += 1e-4
        while submitted - counts["delivered"] < window and submitted < programs:
            submitted += 1
            handle("r1", Submit(program_id=f"p{submitted}", program="noop", work=0.001))
        drain()
        for robot, jobs in running.items():
            for _ in range(min(len(jobs), 8)):
                pid, attempt = jobs.popleft()
                handle(robot, ProgramFinished(program_id=pid, attempt=attempt, ok=True))
        drain()
    cpu = time.process_time() - started
    return {"programs": programs, "window": window, "cpu_us_per_program": cpu / programs * 1e6,
            "reports_per_program": counts["reports"] / programs,
            "ran_on": {name: n.executor.accepted_total for name, n in nodes.items()}}


def driver_burst(programs: int = 5000, window: int = 256) -> dict[str, Any]:
    """The drivers, the core and a client in memory: CPU per program of a
    burst and of calls one at a time (see the module's docstring)."""
    from ramps.testing.memory import MemoryTeam

    state = tempfile.mkdtemp(prefix="ramps-bench-state-")
    quiet = logging.getLogger("ramps")
    level = quiet.level
    quiet.setLevel(logging.ERROR)  # the in-memory team is insecure, and says so
    team = MemoryTeam({name: (2, 1.0) for name in ROBOTS}, settings={"state_dir": state})
    client = None
    try:
        team.run(3.0)
        client = team.connect("r1")

        def run(n: int, in_flight: int) -> tuple[float, Counter[str]]:
            hosts = Counter[str]()
            pending: list[Any] = []
            sent = finished = 0
            started = time.process_time()
            while finished < n:
                while len(pending) < in_flight and sent < n:
                    pending.append(client.submit("noop"))
                    sent += 1
                team.run(0.002)
                left = [f for f in pending if not f.done()]
                for f in pending:
                    if f.done():
                        hosts[f.host or "?"] += 1
                finished += len(pending) - len(left)
                pending = left
            return (time.process_time() - started) / n * 1e6, hosts

        run(200, window)  # warm: imports, first reports, the record's tables
        burst, burst_hosts = run(programs, window)
        calls = max(1, programs // 5)
        one, one_hosts = run(calls, 1)
        return {"programs": programs, "window": window, "burst_cpu_us_per_program": burst,
                "burst_ran_on": dict(burst_hosts), "calls": calls, "one_at_a_time_cpu_us_per_program": one,
                "one_at_a_time_ran_on": dict(one_hosts)}
    finally:
        if client is not None:
            client.close()
        team.close()
        shutil.rmtree(state, ignore_errors=True)
        quiet.setLevel(level)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m ramps.bench.dispatchcpu", description=__doc__.split("\n")[0])
    p.add_argument("--programs", type=int, default=5000, help="no-op programs in each burst")
    p.add_argument("--window", type=int, default=256, help="programs in flight at most during a burst")
    p.add_argument("--out", default="", help="also save the figures as JSON to this file")
    a = p.parse_args(argv)
    if a.programs < 1 or a.window < 1:
        p.error("--programs and --window must be at least 1")
    core = core_burst(a.programs, a.window)
    print(f"core alone: {core['cpu_us_per_program']:.0f} us CPU per program ({a.programs} no-ops, {a.window} in "
          f"flight, {core['reports_per_program']:.2f} reports of the instant per program; ran on {core['ran_on']})")
    drv = driver_burst(a.programs, a.window)
    print(f"drivers, core and client in memory: {drv['burst_cpu_us_per_program']:.0f} us CPU per program in the "
          f"burst (ran on {drv['burst_ran_on']}), {drv['one_at_a_time_cpu_us_per_program']:.0f} us one at a time "
          f"({drv['calls']} calls; ran on {drv['one_at_a_time_ran_on']})")
    if a.out:
        with open(a.out, "w") as f:
            json.dump({"benchmark": "dispatchcpu", "machine": machine(), "core": core, "driver": drv}, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
