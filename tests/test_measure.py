"""What a node's load sampler counts (``ramps.runtime.measure``).

A robot's run queue is what the cost model weighs programs against, so the
node's own threads must not be in it: they wake with every sample and made
an idle emulated robot look 0.1-0.6 tasks busy. A process of the robot's is
counted; a thread of the node is not, however busy.
"""

from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
import threading
import time

import pytest
from runtime_team import RobotCgroup, cgroup_mode, cgroup_support

from ramps.runtime import measure, runqueue, speed_probe

SPIN = '''
import hashlib, json, subprocess, sys, threading, time
from ramps.runtime.measure import LoadSampler, cgroup_dirs
data = b"x" * (32 << 20)
def spin():  # sha256 of a big buffer runs without the GIL: a thread of this process in state R
    while True:
        hashlib.sha256(data).digest()
threading.Thread(target=spin, daemon=True).start()
child = subprocess.Popen([sys.executable, "-c", "while True: pass"])  # another process of the robot
cg, acct = cgroup_dirs()
s = LoadSampler(lambda: 0, scope="cgroup", cgroup=cg, acct=acct, window=2.0, interval=0.05)
import psutil
kid = psutil.Process(child.pid)
def used():  # CPU seconds of this process (its threads) and the child so far
    return time.process_time() + sum(kid.cpu_times()[:2])
s.start()
time.sleep(0.5)
t0, c0 = time.monotonic(), used()
time.sleep(2.0)
cores = (used() - c0) / (time.monotonic() - t0)  # what the two really got over the sampler's window
print(json.dumps(list(s.averages()) + [cores]))
child.kill()
'''


def test_own_threads_are_read_from_open_files_that_follow_threads_coming_and_going():
    own = runqueue.OwnThreads()
    own.running()
    listed = set(os.listdir("/proc/self/task"))
    assert set(own.fds) == listed
    done = threading.Event()
    threads = [threading.Thread(target=done.wait, daemon=True) for _ in range(5)]
    for t in threads:
        t.start()
    for _ in range(own.RELIST):
        own.running()
    assert {str(t.native_id) for t in threads} <= set(own.fds)  # listed again: the new ones are read
    done.set()
    for t in threads:
        t.join()
    for _ in range(own.RELIST):
        own.running()
    assert set(own.fds) == set(os.listdir("/proc/self/task"))  # the ended ones dropped, their files closed
    assert own.running() >= 1  # the caller itself is running


@pytest.mark.slow
@pytest.mark.serial  # measures CPU use: alone
@pytest.mark.skipif(cgroup_support() is not None, reason=f"cpu cgroups unavailable: {cgroup_support()}")
def test_cgroup_run_queue_counts_the_robots_processes_not_the_nodes_threads():
    cg = RobotCgroup(f"measure-{time.monotonic_ns()}", 2.0, cgroup_mode())
    try:
        out = subprocess.run(cg.wrap([sys.executable, "-c", SPIN]), capture_output=True, text=True, timeout=60)
    finally:
        cg.remove()
    assert out.returncode == 0, out.stderr
    busy, runnable, ramps, cores = json.loads(out.stdout.splitlines()[-1])
    assert ramps == 0
    # the busy child: one task; the spinning thread of the sampler's own process is not
    assert 0.5 <= runnable <= 1.4, (busy, runnable)
    # both do use the CPU: busy is what the two got in the same window, however much a loaded
    # host left them (a sampler that left out the node's own threads would see about half)
    assert busy == pytest.approx(cores, rel=0.25), (busy, cores)


@pytest.mark.skipif(cgroup_support() is not None, reason=f"cpu cgroups unavailable: {cgroup_support()}")
def test_a_cgroups_run_queue_follows_processes_that_join_and_leave_it():
    """On a real cgroup: a process that joins after the first sample is counted, one that
    ends is not (an open ``tasks`` file keeps the list it first read: they are opened afresh)."""
    cg = RobotCgroup(f"measure-{time.monotonic_ns()}", 2.0, cgroup_mode())
    spinner = None
    try:
        threads = runqueue.CgroupThreads(cg.dirs[0], cg.dirs[1] if len(cg.dirs) > 1 else None)
        assert threads.sample()[1] == 0
        spinner = subprocess.Popen(cg.wrap([sys.executable, "-c", "while True: pass"]))
        deadline = time.monotonic() + 10
        while threads.sample()[1] != 1 and time.monotonic() < deadline:
            time.sleep(0.05)
        assert threads.sample()[1] == 1
        spinner.kill()
        spinner.wait()
        assert threads.sample()[1] == 0 and not threads._stats
        assert threads.usage() > 0
        threads.close()
    finally:
        if spinner is not None and spinner.poll() is None:
            spinner.kill()
            spinner.wait()
        cg.remove()


def test_own_running_counts_this_processes_busy_threads():
    data = b"x" * (32 << 20)
    stop = threading.Event()

    def spin():
        while not stop.is_set():
            hashlib.sha256(data).digest()

    t = threading.Thread(target=spin, daemon=True)
    before = runqueue.own_running()
    t.start()
    seen = 0
    try:
        for _ in range(50):
            seen = max(seen, runqueue.own_running())
            time.sleep(0.01)
    finally:
        stop.set()
        t.join()
    assert before >= 1  # the caller itself is running
    assert seen >= 2, seen


@pytest.mark.slow
def test_speed_is_scaled_to_the_quota_of_a_core():
    full = speed_probe.measure_speed(0.1)
    assert 0.05 < full < 20
    assert speed_probe.measure_speed(0.1, quota=0.25, cores=1) < full


def test_the_cpu_limit_is_the_smallest_quota_on_the_cgroups_path(tmp_path):
    """A container's limit is often set on a parent (a pod, a slice): the
    node reads every cgroup from its own up, v2 (cpu.max) or v1 files."""
    pod = tmp_path / "pod"
    own = pod / "container"
    own.mkdir(parents=True)
    (pod / "cpu.max").write_text("150000 100000\n")
    (own / "cpu.max").write_text("max 100000\n")
    assert measure.cpu_limit(own) == pytest.approx(1.5)
    (own / "cpu.max").write_text("50000 100000\n")
    assert measure.cpu_limit(own) == pytest.approx(0.5)
    v1 = tmp_path / "v1" / "robot"
    v1.mkdir(parents=True)
    (v1 / "cpu.cfs_quota_us").write_text("32000\n")
    (v1 / "cpu.cfs_period_us").write_text("100000\n")
    assert measure.cpu_limit(v1) == pytest.approx(0.32)
    (v1 / "cpu.cfs_quota_us").write_text("-1\n")
    assert measure.cpu_limit(v1) is None and measure.cpu_limit(None) is None


def test_a_core_under_a_quota_is_its_share_of_a_cpu():
    assert speed_probe.core_fraction(0.32, 4) == pytest.approx(0.08)
    assert speed_probe.core_fraction(None, 4) == speed_probe.core_fraction(8.0, 4) == 1.0


def test_a_measurement_apart_runs_in_a_child_and_brings_its_pieces_back():
    """Re-measured in a forked child (no GIL shared with the node's threads):
    the pieces come back per CPU this process may use, and the child is gone."""
    import os

    busy = threading.Event()
    t = threading.Thread(target=lambda: busy.wait(5), daemon=True)  # a node has other threads
    t.start()
    try:
        pieces = speed_probe.chunk_rates_apart(0.05)
    finally:
        busy.set()
    allowed = os.sched_getaffinity(0)
    assert set(pieces) <= (allowed if len(allowed) > 1 else {-1}) and pieces
    assert all(r > 0 for rates in pieces.values() for r in rates)
    assert sum(len(v) for v in pieces.values()) >= 2 * len(pieces)
    with pytest.raises(ChildProcessError):
        os.waitpid(-1, os.WNOHANG)  # no child left behind


def test_a_measurement_apart_is_given_up_when_a_program_starts():
    """A re-measurement's child takes a robot of small quota-sliced cores' whole
    quota for about a second: when ``stop`` says a program started, the child is
    killed and nothing is measured; asked with nothing starting, it measures."""
    import os

    asked = []

    def program_started() -> bool:
        asked.append(1)
        return len(asked) >= 2  # the second look: a program came

    with pytest.raises(speed_probe.Interrupted):
        speed_probe.chunk_rates_apart(30.0, program_started)  # 30 s of CPU if left alone
    assert len(asked) == 2
    with pytest.raises(ChildProcessError):
        os.waitpid(-1, os.WNOHANG)  # the child is killed and reaped
    assert not speed_probe.MEASURING_PIDS
    samples = speed_probe.SpeedSamples()
    with pytest.raises(speed_probe.Interrupted):
        speed_probe.measure_speed(30.0, samples=samples, apart=True, stop=lambda: True)
    assert samples.latest == 0.0 and samples.rate() == 0.0  # nothing added
    assert speed_probe.chunk_rates_apart(0.02, lambda: False)  # never told to stop: it measures


def test_the_measuring_child_is_the_nodes_own_work_not_the_robots_load(tmp_path, monkeypatch):
    """While a re-measurement's child runs, the robot's run queue leaves it out,
    as it leaves out the node's threads: counted, every idle robot looked busy
    for a second to the origins placing then."""
    import os

    other = subprocess.Popen(["sleep", "30"])  # another process of the robot
    seen: dict[str, object] = {}
    real_waitpid = os.waitpid

    def waitpid(pid: int, flags: int):  # the parent, its child's pieces read: what does the run queue read now?
        if pid == other.pid:
            return real_waitpid(pid, flags)
        (tmp_path / "tasks").write_text(f"{os.getpid()}\n{pid}\n{other.pid}\n")
        threads = runqueue.CgroupThreads(tmp_path, None)
        threads.sample()
        paths: list[str] = []
        monkeypatch.setattr(runqueue, "_running", lambda ps: paths.extend(ps) or 0)
        runqueue.own_running()
        monkeypatch.setattr(runqueue, "_running", real_running)
        seen.update(pid=pid, read=set(threads._stats), paths=paths, during=set(measure.MEASURING_PIDS))
        threads.close()
        return real_waitpid(pid, flags)

    real_running = runqueue._running
    monkeypatch.setattr(os, "waitpid", waitpid)
    try:
        speed_probe.chunk_rates_apart(0.02)
    finally:
        other.kill()
        other.wait()
    pid = seen["pid"]
    assert seen["during"] == {str(pid)}
    # the robot's queue reads the other process only, not the child nor this process; the node's
    # own count reads the child
    assert seen["read"] == {str(other.pid)}
    assert seen["paths"] == [f"/proc/{pid}/stat"]
    assert measure.MEASURING_PIDS == set()  # gone with its child


def test_a_cgroups_threads_are_read_from_open_files_that_follow_threads_and_cgroups(tmp_path):
    """Each thread's stat stays open between samples; a cgroup
    below (a program's cap) is found when the list is made again, a thread that ended is dropped."""
    sleeper = subprocess.Popen(["sleep", "30"])
    spinner = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        (tmp_path / "tasks").write_text(f"{sleeper.pid}\n")
        threads = runqueue.CgroupThreads(tmp_path, None)
        deadline = time.monotonic() + 10
        while threads.sample()[1] and time.monotonic() < deadline:  # until it sleeps (exec done)
            time.sleep(0.05)
        assert threads.sample()[1] == 0  # the sleeper is not running
        assert set(threads._stats) == {str(sleeper.pid)}
        (tmp_path / "cap").mkdir()
        (tmp_path / "cap" / "tasks").write_text(f"{spinner.pid}\n")
        time.sleep(0.2)
        counts = [threads.sample()[1] for _ in range(threads.RELIST + 5)]
        assert counts[-1] == 1 and set(threads._stats) == {str(sleeper.pid), str(spinner.pid)}
        spinner.kill()
        spinner.wait()
        threads.sample()
        assert set(threads._stats) == {str(sleeper.pid)}  # its stat fails to read: dropped
        threads.close()
        assert not threads._stats
    finally:
        for p in (sleeper, spinner):
            p.kill()
            p.wait()


def test_an_idle_robot_is_sampled_less_often_until_a_program_runs():
    """No program here: a sample every ``idle_interval``; one runs: every ``interval``
    again, from the next sample on (counts compared within one run)."""
    programs = [0]
    s = measure.LoadSampler(lambda: programs[0], window=60.0, interval=0.02, idle_interval=0.1)
    s.start()
    try:
        time.sleep(0.6)
        idle = len(s._samples)
        programs[0] = 1
        time.sleep(0.6)
        busy = len(s._samples) - idle
    finally:
        s.stop()
    assert idle >= 1 and busy >= 2.5 * idle, (idle, busy)
    assert s.averages()[2] > 0  # the program was counted


def test_a_worker_without_a_program_and_the_fork_server_are_the_nodes_not_the_robots_load(tmp_path):
    """On a cgroup, a fork server's threads are never load, and its workers' only as many as
    programs run: a worker starting (forked to be kept warm) read as work besides programs,
    and a host of a fraction of a core refused programs for it."""
    named = "import ctypes; ctypes.CDLL(None).prctl(15, {name!r}, 0, 0, 0)\nwhile True: pass"
    procs = [subprocess.Popen([sys.executable, "-c", named.format(name=n)])
             for n in (b"ramps-worker", b"ramps-forksrv", b"other")]
    programs = [0]
    try:
        (tmp_path / "tasks").write_text("".join(f"{p.pid}\n" for p in procs))
        threads = runqueue.CgroupThreads(tmp_path, None)
        deadline = time.monotonic() + 10
        while (threads.sample()[1], threads.workers) != (2, 1) and time.monotonic() < deadline:
            time.sleep(0.05)  # until each has named itself
        assert (threads.sample()[1], threads.workers) == (2, 1)  # the worker and the other; not the fork server
        threads.close()
        s = measure.LoadSampler(lambda: programs[0], scope="cgroup", cgroup=tmp_path, window=0.4, interval=0.02)
        s.start()
        try:
            time.sleep(0.6)
            idle = s.averages()
            programs[0] = 1
            time.sleep(0.6)
            one = s.averages()
        finally:
            s.stop()
        assert idle[1:] == (1.0, 0.0)  # the other process alone: the worker runs no program
        assert one[1:] == (2.0, 1.0)  # the program's worker counts now
    finally:
        for p in procs:
            p.kill()
            p.wait()


def test_a_thread_the_node_starts_between_its_listings_is_not_the_robots_load(tmp_path):
    """The node's own threads are listed every few reads; one it starts in between (a
    burst's) is still its own, however busy, not work besides programs."""
    runqueue.own_running()  # the node's threads listed now
    done = threading.Event()
    data = b"x" * (8 << 20)

    def spin() -> None:  # sha256 of a big buffer runs without the GIL: in state R
        while not done.is_set():
            hashlib.sha256(data).digest()

    t = threading.Thread(target=spin, daemon=True)
    t.start()
    try:
        (tmp_path / "tasks").write_text(f"{t.native_id}\n")
        threads = runqueue.CgroupThreads(tmp_path, None)
        assert t.native_id is not None and str(t.native_id) not in runqueue._OWN.tids()  # not listed yet
        assert [threads.sample()[1] for _ in range(20)] == [0] * 20
        threads.close()
    finally:
        done.set()
        t.join()
