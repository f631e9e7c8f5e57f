"""Per-program CPU caps on the testbed (ramps.testbed.caps): every program and
busy process of a robot runs in a child cgroup whose quota is its
processor-sharing share, so a lone program runs at one emulated core, not on
the whole robot. The tests on a testbed need root and cgroup v1 (skipped otherwise)."""

from __future__ import annotations

import time
from pathlib import Path

import pytest

from test_testbed import REASON, others_leftovers, wait_until

from ramps.runtime.localteam import cgroup_mode
from ramps.core.cost import nice_weight
from ramps.testbed.caps import CFS_PERIOD_US, niceness, shares

needs_caps = pytest.mark.skipif(REASON is not None or cgroup_mode() != "v1",
                                reason=REASON or "per-program caps need cgroup v1")


def test_shares_are_processor_sharing():
    assert shares(0.1, 4, 1) == 0.1
    assert shares(0.1, 4, 4) == 0.1
    assert shares(0.1, 4, 8) == pytest.approx(0.05)
    assert shares(0.2, 2, 3) == pytest.approx(0.2 * 2 / 3)


def test_a_process_niceness_is_read_from_proc():
    import os
    import subprocess
    import sys

    p = subprocess.Popen([sys.executable, "-c", "import os, time; os.nice(7); time.sleep(30)"])
    try:
        mine = os.getpriority(os.PRIO_PROCESS, 0)
        assert wait_until(lambda: niceness(p.pid) == min(19, mine + 7), 10)
        assert niceness(os.getpid()) == os.getpriority(os.PRIO_PROCESS, 0)
    finally:
        p.kill()
        p.wait()
    assert niceness(p.pid) == 0  # gone


def children(tb, robot: str = "r1") -> dict[str, dict]:
    cpu, acct = (Path(d) for d in tb.robots[robot]["cgroup"])
    out = {}
    for c in sorted(p for p in cpu.iterdir() if p.is_dir()):
        try:
            out[c.name] = dict(quota=int((c / "cpu.cfs_quota_us").read_text()),
                               procs=(c / "cgroup.procs").read_text().split(),
                               usage=int((acct / c.name / "cpuacct.usage").read_text()))
        except OSError:
            continue
    return out


def robot_rate(tb, seconds: float, robot: str = "r1") -> float:
    acct = Path(tb.robots[robot]["cgroup"][1])
    u0 = int((acct / "cpuacct.usage").read_text())
    time.sleep(seconds)
    return (int((acct / "cpuacct.usage").read_text()) - u0) / 1e9 / seconds


@pytest.mark.slow
@pytest.mark.serial  # measures CPU shares: run alone
@needs_caps
def test_a_lone_program_runs_at_one_emulated_core_and_busy_processes_share():
    from ramps.testbed import Testbed

    core = 0.2  # 2 emulated cores on 0.4 host cores
    with Testbed(["r1"], cores=2, quota=0.4, speed=0.2) as tb, tb.client("r1", timeout=30.0) as team:
        node = str(tb.robots["r1"]["pid"])
        # both idle workers are in caps of their own; the node is not
        assert wait_until(lambda: len(children(tb)) == 2, 10), children(tb)
        assert all(node not in c["procs"] for c in children(tb).values())
        # 1.4 units: 7 s alone at one emulated core (1 unit ~ 1 CPU second, ramps.programs.burn;
        # on a slower host more); until it is capped alone again below it runs about 4 s at that
        # core, the rest at a sliver, so it still runs then
        fut = team.options(work=1.4).submit("burn", units=1.4)
        assert wait_until(lambda: any(c["quota"] == int(core * CFS_PERIOD_US) and c["usage"] > 2e8
                                      for c in children(tb).values()), 20), children(tb)
        rate = robot_rate(tb, 2.0)
        # capped at one emulated core (0.2), not the robot's 0.4 a lone process would take (a loaded
        # host may give it less: only the bound is asserted)
        assert rate < 0.3, rate
        # two busy processes (nice 0) join: 3 runnable on 2 cores, shared by CFS weight as on a robot;
        # the workers at nice 10 (the busy one and the idle one) weigh 110/1024 of a busy process
        tb.add_load("r1", 2)
        w = nice_weight(10)
        want = [core * x * CFS_PERIOD_US for x in (2 * w / (2 + w),) * 2 + (2 / (2 + w),) * 2]

        def weighted() -> bool:
            # the busy ones (the burn's worker and the two loads) share what the node leaves of
            # the robot (its own use, a few percent, and a 0.5% margin): CFS's proportions, scaled
            # by at most 10%, each moved by what the kernel gave it beyond its share (at most
            # 0.5x-1.5x, ramps.testbed.caps "fair in the end"); the idle worker keeps its share
            got = sorted(c["quota"] for c in children(tb).values())
            if len(got) != 4:
                return False
            scale = got[3] / want[3]
            return 0.85 <= scale <= 1.1 and abs(got[2] - got[3]) <= 0.1 * got[3] and \
                any(abs(g - want[0]) <= 2 for g in got[:2]) and \
                all(0.5 * want[0] * scale - 2 <= g <= 1.5 * want[0] + 2 for g in got[:2])

        assert wait_until(weighted, 10), (children(tb), want)
        # and what they get follows their weights: each load several times the nice-10 program
        before = {n: c["usage"] for n, c in children(tb).items()}
        time.sleep(3.0)
        used = sorted(c["usage"] - before.get(n, c["usage"]) for n, c in children(tb).items())
        assert used[0] < 1e7 and used[2] >= 4 * used[1], used  # the idle worker, the program, the loads
        # two more: 5 runnable on 2 cores, and no one's share by weight comes near a whole core
        # (0.49 each): no cap binds, so every process goes back into the robot's own cgroup,
        # where the kernel shares the robot's whole quota by weight as on a robot
        tb.add_load("r1", 2)
        cpu = Path(tb.robots["r1"]["cgroup"][0])

        def pooled() -> bool:
            procs = (cpu / "cgroup.procs").read_text().split()
            return children(tb) == {} and len(procs) >= 6  # node, four loads, the burn's worker
        assert wait_until(pooled, 10), (children(tb), (cpu / "cgroup.procs").read_text())
        tb.remove_load("r1")  # alone again: capped again, at one emulated core
        assert wait_until(lambda: any(c["quota"] == int(core * CFS_PERIOD_US) and c["usage"] > 2e8
                                      for c in children(tb).values()), 20), children(tb)
        assert fut.result(timeout=120)["iterations"] == 22_400_000
        # a frozen robot: every process in its caps stops too
        tb.freeze("r1")
        states = []
        for c in children(tb).values():
            for pid in c["procs"]:
                states.append(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0])
        assert states and set(states) <= {"T", "t"}, states
        tb.recover("r1")
        tbid = tb.tb
    assert others_leftovers(tbid) == []


@pytest.mark.slow  # not serial: where the program runs and the robot's quota, no CPU share
@needs_caps
def test_without_caps_a_lone_program_takes_the_whole_robot():
    from ramps.testbed import Testbed

    with Testbed(["r1"], cores=2, quota=0.4, speed=0.2, caps=False) as tb, tb.client("r1", timeout=30.0) as team:
        fut = team.options(work=3.0).submit("burn", units=3.0)
        assert wait_until(lambda: fut.state == "running", 20), fut.state
        time.sleep(2.0)  # with caps, a lone program is capped within about a second (the test above)
        # no cap: the program stays in the robot's own cgroup, whose quota is the robot's whole
        # 0.4 host cores (twice an emulated core; what it gets of them depends on the host's load)
        assert children(tb) == {}
        cpu = Path(tb.robots["r1"]["cgroup"][0])
        assert int((cpu / "cpu.cfs_quota_us").read_text()) / int((cpu / "cpu.cfs_period_us").read_text()) \
            == pytest.approx(0.4)
        worker_procs = [pid for pid in (cpu / "cgroup.procs").read_text().split()
                        if "worker" in Path(f"/proc/{pid}/cmdline").read_text(errors="replace")]
        assert worker_procs, "the program's worker runs in the robot's own cgroup"
        fut.cancel()
        tbid = tb.tb
    assert others_leftovers(tbid) == []
