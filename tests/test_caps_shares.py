"""How the testbed's capper shares a robot among its programs
(``ramps.testbed.caps.RobotCaps.tick``), on a cgroup tree made of plain files:
no root, no kernel. The kernel's side (quotas enforced) is in
``tests/test_testbed_caps.py``."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from ramps.testbed.caps import CFS_PERIOD_US, NODE_MARGIN, RobotCaps

QUOTA, CORES = 0.32, 4


class FakeRobot:
    """A robot's cpu and cpuacct cgroups (v1 layout) whose CPU use the test sets."""

    def __init__(self, root: Path) -> None:
        self.cpu, self.acct = root / "cpu" / "robot", root / "cpuacct" / "robot"
        for d in (self.cpu, self.acct):
            d.mkdir(parents=True)
        (self.cpu / "cgroup.procs").write_text("")
        self.used = {"": 0.0}
        self.caps = RobotCaps(self.cpu, self.acct, QUOTA, CORES)

    def child(self, pid: int) -> str:
        name = f"p{pid}"
        for d in (self.cpu, self.acct):
            (d / name).mkdir()
        (self.cpu / name / "cgroup.procs").write_text(f"{pid}\n")
        (self.cpu / name / "cpu.cfs_quota_us").write_text("-1")
        self.used[name] = 0.0
        self._write()
        return name

    def run(self, seconds: float, node: float, per_child: dict[str, float]) -> None:
        """``seconds`` pass: the node uses ``node`` host cores, each child what it is given."""
        for name, cores in per_child.items():
            self.used[name] += cores * seconds
        self.used[""] += node * seconds
        self._write()
        self.caps.tick(seconds)

    def _write(self) -> None:
        children = sum(v for k, v in self.used.items() if k)
        (self.acct / "cpuacct.usage").write_text(str(int((self.used[""] + children) * 1e9)))
        for name, v in self.used.items():
            if name:
                (self.acct / name / "cpuacct.usage").write_text(str(int(v * 1e9)))

    def quota(self, name: str) -> float:
        return int((self.cpu / name / "cpu.cfs_quota_us").read_text()) / CFS_PERIOD_US


@pytest.fixture
def sleepers():
    procs = [subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"]) for _ in range(15)]
    yield [p.pid for p in procs]
    for p in procs:
        p.kill()
        p.wait()


def test_fifteen_busy_programs_share_what_the_node_leaves(tmp_path, sleepers):
    robot = FakeRobot(tmp_path)
    kids = [robot.child(pid) for pid in sleepers]
    for _ in range(30):  # 6 s: the node's average use settles
        robot.run(0.2, node=0.01, per_child={k: QUOTA / 15 for k in kids})
    quotas = [robot.quota(k) for k in kids]
    assert max(quotas) == pytest.approx(min(quotas), rel=0.01)  # processor sharing: equal shares
    # together what the node leaves (its 0.01 host cores), less at most the margin of slack:
    # never over the robot's quota, where the kernel would starve some programs
    assert QUOTA - 0.01 - NODE_MARGIN * QUOTA - 1e-5 <= sum(quotas) <= QUOTA - 0.01 + 1e-5


def test_a_program_the_kernel_starved_is_still_busy(tmp_path, sleepers):
    robot = FakeRobot(tmp_path)
    kids = [robot.child(pid) for pid in sleepers[:4]]
    starved = robot.child(os.getpid())  # this process: running now, so runnable
    for _ in range(10):  # it gets nothing; the others use their whole share
        robot.run(0.2, node=0.0, per_child={k: QUOTA / 5 for k in kids})
    # five busy programs on 4 cores: each gets 4/5 of an emulated core, the starved one too,
    # and together no more than the robot's quota (over it, the kernel starves some further)
    assert robot.quota(starved) == pytest.approx(robot.quota(kids[0]), rel=0.01)
    assert sum(robot.quota(k) for k in kids + [starved]) <= QUOTA


def test_small_moves_of_a_share_leave_the_quota_alone(tmp_path, sleepers):
    # writing a quota refills the child's runtime at once: rewritten every tick, programs overran
    robot = FakeRobot(tmp_path)
    kids = [robot.child(pid) for pid in sleepers]
    for _ in range(10):
        robot.run(0.2, node=0.01, per_child={k: QUOTA / 15 for k in kids})
    (robot.cpu / kids[0] / "cpu.cfs_quota_us").write_text(str(int(robot.quota(kids[0]) * CFS_PERIOD_US) + 7))
    before = robot.quota(kids[0])
    robot.run(0.2, node=0.012, per_child={k: QUOTA / 15 for k in kids})  # the node's use moves a little
    assert robot.quota(kids[0]) == before
    robot.run(0.2, node=0.0, per_child={k: QUOTA / 15 for k in kids[:7]})  # 8 stop: the rest get more
    assert robot.quota(kids[0]) > before * 1.5
