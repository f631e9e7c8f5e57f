"""How soon do programs beyond one per core start? (issue 14)

``python -m ramps.bench.workerstart [--cores 4] [--quota 0.32]
[--programs 12] [--rounds 3] [--out FILE.json]``

A robot of ``--cores`` cores, emulated as a cpu cgroup of ``--quota`` host
cores (as the testbed's robots: 4 cores at 0.08 each = 0.32; root and a cpu
cgroup controller needed, else it runs unconfined and says so), gets
``--programs`` programs at once from its executor's worker pool
(``ramps.runtime.workers.WorkerPool``, the real one). Each program notes the
monotonic time it started and sleeps, so the CPU the robot spends is the
pool's own: starting workers. Printed per round: the delay from submission
to the start of each program (median, max), how many workers the pool
started, and the CPU seconds the robot used (cgroup accounting).

``--death N``: N times, a process that owns a pool of 2 workers running 4
programs is killed alone (SIGKILL, not its group); printed: how long until its
fork server and workers are gone from the process table (they must die with
their node, ``PR_SET_PDEATHSIG``).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import threading
import time
import uuid

import msgspec


def hold(seconds: float = 1.0) -> float:
    """The program: when it started (CLOCK_MONOTONIC, one clock for every process)."""
    started = time.monotonic()
    time.sleep(seconds)
    return started


def _cpu_seconds() -> float | None:
    """CPU time of this process's cgroup (v1 cpuacct or v2 cpu.stat), if readable."""
    try:
        line = open("/proc/self/cgroup").read().splitlines()
    except OSError:
        return None
    for entry in line:
        _, ctrls, path = entry.split(":", 2)
        if "cpuacct" in ctrls.split(","):
            try:
                return int(open(f"/sys/fs/cgroup/cpuacct{path}/cpuacct.usage").read()) / 1e9
            except OSError:
                return None
        if ctrls == "":
            try:
                for row in open(f"/sys/fs/cgroup{path}/cpu.stat"):
                    if row.startswith("usage_usec"):
                        return int(row.split()[1]) / 1e6
            except OSError:
                return None
    return None


def inner(cores: int, programs: int, rounds: int, hold_s: float) -> dict:
    from ramps.runtime.workers import WorkerPool

    done: dict = {}
    ev = threading.Event()

    def finished(key, ok, value, error, retryable, *_):
        done[key] = msgspec.msgpack.decode(value) if ok else error
        if len(done) >= programs:
            ev.set()

    pool = WorkerPool(cores, {"hold": "ramps.bench.workerstart:hold"}, finished, nice=10)
    cpu0 = _cpu_seconds()
    pool.start()
    time.sleep(1.0)  # the pool's first workers are up before the first round
    rounds_out: list[dict] = []
    out: dict[str, object] = {"cores": cores, "programs": programs, "rounds": rounds_out}
    try:
        for r in range(rounds):
            done.clear()
            ev.clear()
            started0, c0 = pool.started, _cpu_seconds()
            t0 = time.monotonic()
            for i in range(programs):
                pool.run((f"p{i}", r + 1), "hold", msgspec.msgpack.encode({"seconds": hold_s}))
            ev.wait(120)
            delays = sorted(v - t0 for v in done.values() if isinstance(v, float))
            c1 = _cpu_seconds()
            row = {"round": r + 1, "delay_median_s": statistics.median(delays) if delays else None,
                   "delay_max_s": delays[-1] if delays else None,
                   "beyond_cores_max_s": delays[-1] if len(delays) > cores else None,
                   "workers_started": pool.started - started0,
                   "cpu_s": None if c0 is None or c1 is None else c1 - c0,
                   "errors": [v for v in done.values() if not isinstance(v, float)]}
            rounds_out.append(row)
            time.sleep(3.0)  # the extra workers retire (RETIRE_AFTER) before the next round
    finally:
        pool.stop()
    out["startup_cpu_s"] = None if cpu0 is None else (_cpu_seconds() or 0) - cpu0
    return out


_OWNER = (
    "import time, msgspec\n"
    "from ramps.runtime.workers import WorkerPool\n"
    "pool = WorkerPool(2, {'hold': 'ramps.bench.workerstart:hold'}, lambda *a: None)\n"
    "pool.start()\n"
    "for i in range(4): pool.run((f'k{i}', 1), 'hold', msgspec.msgpack.encode({'seconds': 60}))\n"
    "while len(pool.pids()) < 4: time.sleep(0.05)\n"
    "print(' '.join(str(p) for p in [pool._server.pid, *pool.pids().values()]), flush=True)\n"
    "time.sleep(120)\n")


def death_times(trials: int) -> list[float]:
    """Seconds from SIGKILL of a pool's owner until its fork server and workers are gone."""
    import signal

    import psutil

    def gone(p: psutil.Process) -> bool:
        try:
            return p.status() == psutil.STATUS_ZOMBIE
        except psutil.NoSuchProcess:
            return True

    out = []
    for _ in range(trials):
        owner = subprocess.Popen([sys.executable, "-c", _OWNER], stdout=subprocess.PIPE, text=True,
                                 start_new_session=True)
        assert owner.stdout is not None  # stdout=PIPE
        try:
            procs = [psutil.Process(int(p)) for p in owner.stdout.readline().split()]
            t0 = time.monotonic()
            os.kill(owner.pid, signal.SIGKILL)
            while not all(gone(p) for p in procs) and time.monotonic() - t0 < 10:
                time.sleep(0.001)
            out.append(time.monotonic() - t0 if all(gone(p) for p in procs) else float("inf"))
        finally:
            try:
                os.killpg(owner.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            owner.wait()
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m ramps.bench.workerstart", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cores", type=int, default=4, help="the robot's cores (its worker pool's size)")
    ap.add_argument("--quota", type=float, default=0.32, help="host cores the robot's cgroup may use (0: no cgroup)")
    ap.add_argument("--programs", type=int, default=12, help="programs submitted at once")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--hold", type=float, default=4.0, help="seconds each program sleeps")
    ap.add_argument("--out", help="save the figures as JSON here")
    ap.add_argument("--death", type=int, default=0, metavar="N",
                    help="instead: N times, kill a pool's owner alone and time its workers' end")
    ap.add_argument("--inner", action="store_true", help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.inner:
        print(json.dumps(inner(a.cores, a.programs, a.rounds, a.hold)))
        return 0
    if a.death:
        times = death_times(a.death)
        print("fork server and 4 workers gone after SIGKILL of their owner alone: "
              + ", ".join(f"{t * 1000:.1f} ms" for t in times))
        if a.out:
            with open(a.out, "w") as f:
                json.dump({"death_s": times}, f, indent=1)
        return 0 if all(t < 1.0 for t in times) else 1
    cmd = [sys.executable, "-m", "ramps.bench.workerstart", "--inner", "--cores", str(a.cores),
           "--programs", str(a.programs), "--rounds", str(a.rounds), "--hold", str(a.hold)]
    cg = None
    mode = "unconfined (no cgroup: not root or no cpu controller)"
    if a.quota > 0 and os.geteuid() == 0:
        from ramps.runtime.localteam import RobotCgroup, cgroup_mode

        m = cgroup_mode()
        if m is not None:
            cg = RobotCgroup(f"ramps-workerstart-{uuid.uuid4().hex[:8]}", a.quota, m)
            cmd = cg.wrap(cmd)
            mode = f"a cpu cgroup of {a.quota:g} host cores ({m})"
    try:
        res = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    finally:
        if cg is not None:
            cg.remove()
    if res.returncode != 0:
        print(res.stderr, file=sys.stderr)
        return res.returncode
    out = json.loads(res.stdout.strip().splitlines()[-1])
    out["mode"] = mode
    print(f"robot: {a.cores} cores in {mode}; {a.programs} programs submitted at once, each sleeps {a.hold:g} s")
    print(f"pool start-up CPU (first {a.cores} workers): {out['startup_cpu_s']}")
    print("round  start delay median  max      workers started  robot CPU s")
    for r in out["rounds"]:
        fmt = (lambda v: "-" if v is None else f"{v:.3f}")
        print(f"{r['round']:>5}  {fmt(r['delay_median_s']):>18}  {fmt(r['delay_max_s']):>7}  "
              f"{r['workers_started']:>15}  {fmt(r['cpu_s']):>11}" + (f"  errors: {r['errors']}" if r["errors"] else ""))
    if a.out:
        with open(a.out, "w") as f:
            json.dump(out, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
