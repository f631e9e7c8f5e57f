"""How the testbed's capper shares a robot among its programs
(``ramps.testbed.caps.RobotCaps.tick``), on a cgroup tree made of plain files
that moves processes between cgroups as the kernel does: no root, no kernel.
The kernel's side (quotas enforced) is in ``tests/test_testbed_caps.py``."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from ramps.testbed.caps import CFS_PERIOD_US, NODE_MARGIN, QUOTA_SHORT, RobotCaps

QUOTA, CORES = 0.32, 4
CORE = QUOTA / CORES


class FakeCaps(RobotCaps):
    """The real capper on a plain-file cgroup tree: joining a cgroup takes the
    process out of its old one, a cgroup with processes cannot be removed, and
    a process's CPU and run state are what the test says."""

    def __init__(self, robot: FakeRobot) -> None:
        super().__init__(robot.cpu, robot.acct, QUOTA, CORES)
        self.robot = robot

    def _join(self, cgroup: Path, pid: int) -> None:
        base = self.cpu if cgroup.is_relative_to(self.cpu) else self.acct
        for d in [base, *(c for c in base.iterdir() if c.is_dir())]:
            procs = (d / "cgroup.procs").read_text().split() if (d / "cgroup.procs").exists() else []
            (d / "cgroup.procs").write_text("".join(f"{p}\n" for p in procs if p != str(pid)))
        procs = (cgroup / "cgroup.procs").read_text() if (cgroup / "cgroup.procs").exists() else ""
        (cgroup / "cgroup.procs").write_text(procs + f"{pid}\n")
        self.robot.since[pid] = self.robot.used[pid]  # a new cgroup counts CPU from now

    def _remove(self, cgroup: Path) -> None:
        if not (cgroup / "cgroup.procs").read_text().split():
            shutil.rmtree(cgroup)

    def _proc_cpu(self, pid: int) -> tuple[float, bool] | None:
        return self.robot.used[pid], pid in self.robot.runnable


class FakeRobot:
    """A robot's cpu and cpuacct cgroups (v1 layout) holding ``pids``, whose
    CPU use the test sets."""

    def __init__(self, root: Path, pids: list[int], period_us: int | None = None) -> None:
        self.cpu, self.acct = root / "cpu" / "robot", root / "cpuacct" / "robot"
        for d in (self.cpu, self.acct):
            d.mkdir(parents=True)
            (d / "cgroup.procs").write_text("".join(f"{p}\n" for p in pids))
        if period_us is not None:
            (self.cpu / "cpu.cfs_period_us").write_text(f"{period_us}\n")
        self.node = 0.0
        self.used = {pid: 0.0 for pid in pids}
        self.since = dict(self.used)
        self.runnable: set[int] = set()
        self.caps = FakeCaps(self)
        self._write()
        self.caps.adopt(None)  # every process into a child of its own, as the testbed starts

    def run(self, seconds: float, node: float, per_pid: dict[int, float]) -> None:
        """``seconds`` pass: the node uses ``node`` host cores, each process what it is given."""
        for pid, cores in per_pid.items():
            self.used[pid] += cores * seconds
        self.node += node * seconds
        self._write()
        self.caps.adopt(None)
        self.caps.tick(seconds)

    def _write(self) -> None:
        (self.acct / "cpuacct.usage").write_text(str(int((self.node + sum(self.used.values())) * 1e9)))
        for pid, v in self.used.items():
            if (self.acct / f"p{pid}").is_dir():
                (self.acct / f"p{pid}" / "cpuacct.usage").write_text(str(int((v - self.since[pid]) * 1e9)))

    def children(self) -> list[str]:
        return sorted(c.name for c in self.cpu.iterdir() if c.is_dir())

    def in_robot(self) -> list[int]:
        return sorted(int(p) for p in (self.cpu / "cgroup.procs").read_text().split())

    def quota(self, pid: int) -> float:
        return int((self.cpu / f"p{pid}" / "cpu.cfs_quota_us").read_text()) / CFS_PERIOD_US


def _sleepers(n: int, nice: int = 0) -> list[subprocess.Popen]:
    return [subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"],
                             preexec_fn=(lambda: os.nice(nice)) if nice else None) for _ in range(n)]


@pytest.fixture
def sleepers():
    procs = _sleepers(15)
    yield [p.pid for p in procs]
    for p in procs:
        p.kill()
        p.wait()


@pytest.fixture
def heavy_and_light():
    """Two processes at nice 0 (background load) and four at nice 10 (programs)."""
    heavy, light = _sleepers(2), _sleepers(4, nice=10)
    yield [p.pid for p in heavy], [p.pid for p in light]
    for p in heavy + light:
        p.kill()
        p.wait()


def test_a_full_robot_has_no_caps_and_is_capped_again_when_a_share_reaches_a_core(tmp_path, sleepers):
    robot = FakeRobot(tmp_path, sleepers)
    assert robot.children() == [f"p{pid}" for pid in sorted(sleepers)] and robot.in_robot() == []
    for _ in range(3):  # fifteen busy programs on 4 cores: nobody's share reaches a core
        robot.run(0.2, node=0.01, per_pid={p: QUOTA / 15 for p in sleepers})
    # no cap binds: every program back in the robot's own cgroup, shared by the kernel
    assert robot.caps.pooled and robot.children() == [] and robot.in_robot() == sorted(sleepers)
    for _ in range(3):  # still full: pooled it stays (the node's averaged use is not touched)
        robot.run(0.2, node=0.01, per_pid={p: QUOTA / 15 for p in sleepers})
    assert robot.caps.pooled and robot.children() == []
    # twelve finish (idle now), three run on: each would reach a whole core, so caps again,
    # at one emulated core each
    busy = sleepers[:3]
    robot.run(0.2, node=0.01, per_pid={p: QUOTA / 4 for p in busy})
    assert not robot.caps.pooled and robot.in_robot() == []
    assert robot.children() == [f"p{pid}" for pid in sorted(sleepers)]
    robot.run(0.2, node=0.01, per_pid={p: CORE for p in busy})
    assert [robot.quota(p) for p in busy] == [pytest.approx(CORE, rel=0.01)] * 3


def test_a_program_the_kernel_starved_keeps_the_robot_full(tmp_path, sleepers):
    # seven programs use their share, the kernel gives the eighth nothing: it is runnable all
    # the same, so eight programs fill the 4 cores (half a core each) and the robot stays
    # pooled (counted idle, the seven would be capped, the eighth waiting for a tick)
    robot = FakeRobot(tmp_path, sleepers[:8])
    for _ in range(3):
        robot.run(0.2, node=0.0, per_pid={p: QUOTA / 8 for p in sleepers[:8]})
    assert robot.caps.pooled
    robot.runnable = {sleepers[7]}
    for _ in range(3):
        robot.run(0.2, node=0.0, per_pid={p: QUOTA / 7 for p in sleepers[:7]})
    assert robot.caps.pooled and robot.children() == []
    robot.runnable = set()  # it exited meanwhile, say: seven on four cores are capped
    robot.run(0.2, node=0.0, per_pid={p: QUOTA / 7 for p in sleepers[:7]})
    assert not robot.caps.pooled
    for _ in range(3):
        robot.run(0.2, node=0.0, per_pid={p: QUOTA / 7 for p in sleepers[:7]})
    assert [robot.quota(p) for p in sleepers[:7]] == [pytest.approx(QUOTA / 7, rel=0.02)] * 7


def test_five_programs_on_four_cores_are_capped_not_pooled(tmp_path, sleepers):
    # 0.8 of a core each: pooled, the kernel ran them unevenly for seconds; capped, each at
    # its share of what the node leaves
    robot = FakeRobot(tmp_path, sleepers[:5])
    for _ in range(5):
        robot.run(0.2, node=0.0, per_pid={p: QUOTA / 5 for p in sleepers[:5]})
    assert not robot.caps.pooled and robot.in_robot() == []
    assert [robot.quota(p) for p in sleepers[:5]] == [pytest.approx(QUOTA / 5, rel=0.02)] * 5


def test_capped_shares_follow_cfs_weights_and_leave_the_node_its_use(tmp_path, heavy_and_light):
    heavy, light = heavy_and_light
    robot = FakeRobot(tmp_path, heavy + light)
    # two busy processes at nice 0 and four programs at nice 10 on 4 cores: the two would have
    # more than a core each by weight, so they are capped at one, and the four share the other
    # two; all six together what the node leaves of the robot's quota
    for _ in range(30):  # 6 s: the node's average use settles
        robot.run(0.2, node=0.01, per_pid={p: CORE for p in heavy} | {p: CORE / 2 for p in light})
    assert not robot.caps.pooled
    h, lt = [robot.quota(p) for p in heavy], [robot.quota(p) for p in light]
    assert max(h) == pytest.approx(min(h), rel=0.01) and max(lt) == pytest.approx(min(lt), rel=0.01)
    assert h[0] == pytest.approx(2 * lt[0], rel=0.02)  # a core each against half a core each
    room = QUOTA - 0.01  # less a margin, and quotas are rewritten once they fall short by 1%
    assert (room - NODE_MARGIN * QUOTA) * (1 - QUOTA_SHORT) - 1e-5 <= sum(h + lt) <= room + 1e-5


def test_small_moves_of_a_share_leave_the_quota_alone(tmp_path, heavy_and_light):
    # writing a quota refills the child's runtime at once: rewritten every tick, programs overran
    heavy, light = heavy_and_light
    robot = FakeRobot(tmp_path, heavy + light)
    busy = {p: CORE for p in heavy} | {p: CORE / 2 for p in light}
    for _ in range(30):  # the node's average use settles
        robot.run(0.2, node=0.01, per_pid=busy)
    p0 = light[0]
    (robot.cpu / f"p{p0}" / "cpu.cfs_quota_us").write_text(str(int(robot.quota(p0) * CFS_PERIOD_US) + 7))
    before = robot.quota(p0)
    robot.run(0.2, node=0.009, per_pid=busy)  # the node's use moves a little (down: not over the quota)
    assert robot.quota(p0) == before
    robot.run(0.2, node=0.0, per_pid={p: CORE for p in heavy + light[:1]})  # 3 stop: the rest get more
    assert robot.quota(p0) > before * 1.5


def test_a_program_adopted_between_ticks_is_not_counted_as_the_nodes_use(tmp_path, sleepers):
    # the capper adopts new processes four times a tick: a worker that starts a program is moved
    # into a child of its own, and the CPU it uses until the next tick is the program's
    first, late = sleepers[:3], sleepers[3]
    robot = FakeRobot(tmp_path, first)
    for _ in range(30):  # the node's average use settles at its 0.01 host cores
        robot.run(0.2, node=0.01, per_pid={p: CORE for p in first})
    settled = robot.caps.node_use
    assert settled == pytest.approx(0.01, rel=0.05)
    robot.used[late] = robot.since[late] = 0.0
    with open(robot.cpu / "cgroup.procs", "a") as f:  # the fork server's new worker, born in the robot
        f.write(f"{late}\n")
    robot.caps.adopt(None)
    assert f"p{late}" in robot.children()
    robot.run(0.2, node=0.01, per_pid={p: CORE for p in [*first, late]})  # it runs a program until the tick
    assert robot.caps.node_use == pytest.approx(settled, rel=0.05)


def _kernel(robot: FakeRobot, pids: list[int], bias: dict[int, float], room: float) -> dict[int, float]:
    """What a throttled robot's children get in a period, as the kernel hands it out: the
    robot's room split by quota, weighed by how much the kernel favours each (its slices
    outlast a period on one CPU, a write of its quota refills it...)."""
    weighed = {p: robot.quota(p) * bias[p] for p in pids}
    return {p: room * w / sum(weighed.values()) for p, w in weighed.items()}


def test_a_crowded_robot_evens_out_what_the_kernel_gives_its_children(tmp_path, sleepers):
    # four programs fill a robot of four cores; the kernel favours the first and starves the
    # last (measured: 0.063-0.070 against 0.031-0.038 host cores under equal quotas): each
    # child's quota moves by what it is owed, so in the end they get the same CPU
    four = sleepers[:4]
    bias = {four[0]: 1.5, four[1]: 1.0, four[2]: 1.0, four[3]: 0.7}
    robot = FakeRobot(tmp_path, four)
    room = QUOTA - 0.01
    for _ in range(5):
        robot.run(0.2, node=0.01, per_pid={p: room / 4 for p in four})
    for _ in range(20):  # 4 s to even out
        robot.run(0.2, node=0.01, per_pid=_kernel(robot, four, bias, room))
    start = dict(robot.used)
    for _ in range(20):  # then 4 s
        robot.run(0.2, node=0.01, per_pid=_kernel(robot, four, bias, room))
    got = [robot.used[p] - start[p] for p in four]
    assert max(got) / min(got) < 1.08, got  # without the correction: 1.5 / 0.7 = 2.1
    assert robot.quota(four[3]) > robot.quota(four[0]) * 1.5  # the starved one's quota is raised


def test_a_robot_with_room_to_spare_keeps_each_program_at_its_share(tmp_path, sleepers):
    # three programs on four cores: the robot's quota does not bind, each child's own does;
    # chasing what the kernel gives would only rewrite quotas (each write refills a child)
    three = sleepers[:3]
    robot = FakeRobot(tmp_path, three)
    for _ in range(10):
        robot.run(0.2, node=0.01, per_pid={three[0]: CORE * 1.2, three[1]: CORE, three[2]: CORE * 0.8})
    assert [robot.quota(p) for p in three] == [pytest.approx(CORE, rel=0.01)] * 3


def test_children_take_the_robots_cfs_period(tmp_path, sleepers):
    # a robot made with a 20 ms period (``Testbed(period_us=)``: emulated cores that hold for
    # calls shorter than 100 ms): its programs' caps are quotas over 20 ms too
    robot = FakeRobot(tmp_path, sleepers[:3], period_us=20_000)
    p = sleepers[0]
    assert (robot.cpu / f"p{p}" / "cpu.cfs_period_us").read_text() == "20000"
    robot.run(0.2, node=0.0, per_pid={q: CORE for q in sleepers[:3]})
    assert int((robot.cpu / f"p{p}" / "cpu.cfs_quota_us").read_text()) == pytest.approx(CORE * 20000, rel=0.01)
