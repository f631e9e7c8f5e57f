"""The executor's worker pool runs every program at once (processor sharing,
as the cost model assumes), grows past its cores on demand up to a limit,
and shrinks back when the extra workers fall idle."""

from __future__ import annotations

import os
import threading
import time
from pathlib import Path

import msgspec
import pytest

from ramps.runtime.workers import WorkerPool

# every test starts a worker pool: real processes
pytestmark = pytest.mark.slow

TESTS = str(Path(__file__).parent)
TARGETS = {"sleepy": "e2eprogs:sleepy", "where": "e2eprogs:where", "stamp": "e2eprogs:stamp",
           "burn": "ramps.programs.burn:burn"}


def wait_until(pred, timeout: float, step: float = 0.02) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(step)
    return pred()


def make_pool(size: int, max_size: int | None = None, cpu: dict | None = None, core_share: float = 1.0):
    done: dict = {}
    ev = threading.Event()

    def finished(key, ok, value, error, retryable, cpu_s=None, died=False):
        if cpu is not None:
            cpu[key] = cpu_s
        done[key] = (ok, msgspec.msgpack.decode(value) if ok else error, retryable)
        ev.set()

    env = dict(os.environ, PYTHONPATH=os.pathsep.join([TESTS, os.environ.get("PYTHONPATH", "")]))
    pool = WorkerPool(size, TARGETS, finished, env=env, max_size=max_size, core_share=core_share)
    pool.start()
    return pool, done


def args(**kw) -> bytes:
    return msgspec.msgpack.encode(kw)


def test_a_finished_program_reports_the_cpu_seconds_it_used_not_the_time_it_slept():
    """What a host counts a program's work from (``ProgramFinished.cpu_s``):
    a burn's CPU seconds, a sleeper's next to none, measured in one run."""
    cpu: dict = {}
    pool, done = make_pool(2, cpu=cpu)
    try:
        pool.run(("b", 1), "burn", args(units=0.3))
        pool.run(("s", 1), "sleepy", args(seconds=1.0, tag="s"))
        assert wait_until(lambda: len(done) == 2, 30), done
        assert all(ok for ok, _, _ in done.values())
        burned, slept = cpu[("b", 1)], cpu[("s", 1)]
        assert burned > 0.05 and slept is not None
        assert slept < burned / 5, (burned, slept)
    finally:
        pool.stop()


def test_a_call_of_a_few_milliseconds_counts_the_cpu_it_used_not_zero():
    """``os.times`` counts clock ticks (10 ms): a warm-up call of a few
    milliseconds measured 0 CPU seconds, and its host reported no work."""
    cpu: dict = {}
    pool, done = make_pool(1, cpu=cpu)
    try:
        pool.run(("t", 1), "burn", args(units=0.002))
        assert wait_until(lambda: len(done) == 1, 30), done
        assert 0 < cpu[("t", 1)] < 1.0, cpu
    finally:
        pool.stop()


def test_more_programs_than_cores_all_run_at_once_then_extra_workers_retire():
    pool, done = make_pool(1)
    try:
        keys = [(f"p{i}", 1) for i in range(3)]
        for k in keys:
            pool.run(k, "sleepy", args(seconds=1.5, tag=k[0]))
        # three programs on one core: three worker processes run them together
        assert wait_until(lambda: len(pool.pids()) == 3, 10), pool.pids()
        assert pool.queued() == 0 and pool.busy() == 3
        assert len(set(pool.pids().values())) == 3
        assert wait_until(lambda: len(done) == 3, 20), done
        assert all(ok for ok, _, _ in done.values())
        assert len({v["pid"] for _, v, _ in done.values()}) == 3
        # idle again: back to one worker per core
        assert wait_until(lambda: len(pool._workers) == 1, 10), len(pool._workers)
    finally:
        pool.stop()


def test_beyond_the_limit_programs_wait_in_order():
    pool, done = make_pool(1, max_size=2)
    try:
        for i in range(3):
            pool.run((f"q{i}", 1), "sleepy", args(seconds=0.8, tag=f"q{i}"))
        assert wait_until(lambda: pool.busy() == 2, 10)
        assert pool.queued() == 1
        assert ("q2", 1) not in pool.pids()  # first come, first served
        assert wait_until(lambda: len(done) == 3, 20), done
        assert len(pool._workers) <= 2
    finally:
        pool.stop()


def test_cancel_of_an_extra_worker_program_reports_nothing_and_the_pool_recovers():
    pool, done = make_pool(1)
    try:
        pool.run(("a", 1), "sleepy", args(seconds=5.0))
        pool.run(("b", 1), "sleepy", args(seconds=0.3))
        assert wait_until(lambda: len(pool.pids()) == 2, 10)
        pool.cancel(("a", 1))
        assert wait_until(lambda: ("b", 1) in done, 10)
        time.sleep(0.3)
        assert ("a", 1) not in done  # the core already knows it cancelled it
        assert wait_until(lambda: len(pool._workers) == 1, 10), len(pool._workers)
        pool.run(("c", 1), "sleepy", args(seconds=0.1))
        assert wait_until(lambda: ("c", 1) in done, 10)
    finally:
        pool.stop()


def test_a_burst_of_tiny_programs_is_served_without_new_workers():
    """Starting a worker costs more than a tiny program: while the workers keep
    finishing programs, a queue of them does not make the pool grow."""
    pool, done = make_pool(1)
    try:
        for i in range(300):
            pool.run((f"w{i}", 1), "where", args(x=i))
        assert wait_until(lambda: len(done) == 300, 60), len(done)
        assert all(ok for ok, _, _ in done.values())
        assert pool.started <= 3, pool.started  # 1, give or take a hiccup of a slow machine
    finally:
        pool.stop()


def test_programs_beyond_the_cores_all_run_at_once():
    """Eight programs on a one-core robot (its limit: 8 workers per core):
    the seven extra workers come from the fork server in milliseconds, so all
    eight run together (each sleeps 1.2 s). Booting a fresh interpreter per
    worker, one per GROW_AFTER (0.2 s), started the eighth after the first
    had ended."""
    pool, done = make_pool(1)
    try:
        keys = [(f"x{i}", 1) for i in range(8)]
        for k in keys:
            pool.run(k, "stamp", args(seconds=1.2))
        assert wait_until(lambda: len(done) == 8, 30), done
        spans = [v for ok, v, _ in done.values() if ok]
        assert len(spans) == 8, done
        last_start, first_end = max(s for s, _ in spans), min(e for _, e in spans)
        assert last_start < first_end, f"not all at once: last started {last_start - first_end:.2f} s after the first ended"
        assert pool.forked >= 8  # every worker came from the fork server
    finally:
        pool.stop()


def test_fork_server_and_workers_die_with_their_pool_process(tmp_path):
    """A process that owns a pool is SIGKILLed: its fork server and its
    workers, mid-program, are gone (checked in the process table) at once."""
    import signal
    import subprocess
    import sys

    import psutil

    script = (
        "import os, sys, time, msgspec\n"
        "from ramps.runtime.workers import WorkerPool\n"
        "pool = WorkerPool(1, {'sleepy': 'e2eprogs:sleepy'}, lambda *a: None)\n"
        "pool.start()\n"
        "for i in range(3):\n"
        "    pool.run((f'k{i}', 1), 'sleepy', msgspec.msgpack.encode({'seconds': 60}))\n"
        "while len(pool.pids()) < 3: time.sleep(0.05)\n"
        "print(' '.join(str(p) for p in [pool._server.pid, *pool.pids().values()]), flush=True)\n"
        "time.sleep(120)\n"
    )
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([TESTS, os.environ.get("PYTHONPATH", "")]))
    owner = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, env=env, text=True,
                             start_new_session=True)
    try:
        pids = [int(p) for p in owner.stdout.readline().split()]
        assert len(pids) == 4, pids
        procs = [psutil.Process(p) for p in pids]
        os.kill(owner.pid, signal.SIGKILL)  # the owner alone, not its group
        owner.wait(5)

        def gone(p):
            try:
                return p.status() == psutil.STATUS_ZOMBIE
            except psutil.NoSuchProcess:
                return True

        assert wait_until(lambda: all(gone(p) for p in procs), 1.0), [p.pid for p in procs if not gone(p)]
    finally:
        try:
            os.killpg(owner.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        owner.wait(5)


def test_the_pool_waits_for_starved_programs_and_grows_for_a_long_one(monkeypatch):
    """Two programs on a one-core robot, the running one runnable but given
    no CPU (a host busy with other work, as ``/proc`` says): the second waits
    for the first rather than splitting that CPU with it. Once the running
    one gets its CPU (a long program), the pool grows and the second runs."""
    import ramps.runtime.workers as workers

    cpu = {"s": 5.0}
    monkeypatch.setattr(workers._Worker, "cpu", lambda self: (cpu["s"], "R"))
    pool, done = make_pool(1)
    try:
        pool.run(("long", 1), "sleepy", args(seconds=60))
        pool.run(("short", 1), "sleepy", args(seconds=0.05))
        time.sleep(10 * workers.GROW_AFTER)
        assert pool.forked == 1 and pool.queued() == 1 and not done  # starved: no new worker
        cpu["s"] += 10 * workers.STARVED_CPU  # the running program gets its CPU
        assert wait_until(lambda: ("short", 1) in done, 30), done
        assert pool.forked == 2 and done[("short", 1)][0]
    finally:
        pool.stop()


def test_on_a_robot_whose_cores_are_slices_of_a_host_a_program_getting_its_share_is_not_starved(monkeypatch):
    """A robot of 4 cores on 0.2 host cores (a container's quota, an emulated
    robot): a running program that gets its 0.05 host cores is not starved,
    so a program beyond the cores gets a worker after GROW_AFTER, not after
    STARVED_CPU of host CPU (2 s at that share). On a robot of whole cores
    the same CPU is a starved program's, and the queue waits."""
    import ramps.runtime.workers as workers

    for share, grows in ((0.05, True), (1.0, False)):
        cpu = {"s": 5.0}
        monkeypatch.setattr(workers._Worker, "cpu", lambda self, cpu=cpu: (cpu["s"], "R"))
        pool, done = make_pool(1, core_share=share)
        try:
            pool.run(("long", 1), "sleepy", args(seconds=60))
            pool.run(("short", 1), "sleepy", args(seconds=0.05))
            time.sleep(3 * workers.GROW_AFTER)
            cpu["s"] += 2 * workers.STARVED_CPU * 0.05  # what its share gives it in about two GROW_AFTERs
            if grows:
                assert wait_until(lambda: ("short", 1) in done, 30), done
                assert pool.forked == 2
            else:
                time.sleep(10 * workers.GROW_AFTER)
                assert pool.forked == 1 and pool.queued() == 1 and not done
        finally:
            pool.stop()


def test_the_pool_grows_as_before_where_the_busy_worker_sleeps_or_cannot_be_seen(monkeypatch):
    """A running program that sleeps (I/O, an executable's child: not
    runnable) or whose process cannot be read (not Linux) does not hold the
    queue back: a new worker comes after GROW_AFTER."""
    import ramps.runtime.workers as workers

    for seen in ((5.0, "S"), None):
        monkeypatch.setattr(workers._Worker, "cpu", lambda self, seen=seen: seen)
        pool, done = make_pool(1)
        try:
            pool.run(("long", 1), "sleepy", args(seconds=60))
            pool.run(("short", 1), "sleepy", args(seconds=0.05))
            assert wait_until(lambda: ("short", 1) in done, 30), (seen, done)
            assert pool.forked == 2
        finally:
            pool.stop()


def test_proc_cpu_reads_a_live_process_and_none_for_a_gone_one():
    from ramps.runtime.measure import proc_cpu

    seen = proc_cpu(os.getpid())
    assert seen is not None and seen[0] > 0 and seen[1] == "R"  # this process, running this line
    assert proc_cpu(2**22 + 12345) is None  # beyond any pid


def test_a_workers_cpu_is_read_again_from_its_open_stat_file():
    import subprocess
    import sys

    from ramps.runtime.measure import proc_cpu, stat_cpu

    spin = "import time\nt = time.process_time()\nwhile time.process_time() - t < 0.3: pass\ntime.sleep(30)"
    child = subprocess.Popen([sys.executable, "-c", spin])
    fd = os.open(f"/proc/{child.pid}/stat", os.O_RDONLY)
    try:
        first = stat_cpu(fd)
        assert first is not None
        deadline = time.monotonic() + 20
        while (seen := stat_cpu(fd)) is not None and seen[0] < 0.3 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert seen is not None and seen[0] >= 0.3 > first[0]  # the same open file, read afresh
        assert seen[0] == pytest.approx(proc_cpu(child.pid)[0], abs=0.05)
        child.kill()
        child.wait()
        assert stat_cpu(fd) is None  # reaped: gone
    finally:
        os.close(fd)
        if child.poll() is None:
            child.kill()
            child.wait()
