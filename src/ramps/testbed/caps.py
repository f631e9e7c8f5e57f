"""Per-program CPU caps on the testbed (docs/lab/2026-11-23-testbed.md, "caps").

How this works: a robot is one cpu cgroup whose quota makes it ``cores``
emulated cores of ``quota / cores`` host cores each. Without more, a robot
running one program would run it on the whole quota, ``cores`` times faster
than one emulated core, and the processor-sharing model the simulator and the
cost model use would not hold. So one small process per testbed (``python -m
ramps.testbed.caps STATE_FILE``, started by ``Testbed.up``) moves every
process of a robot except its node (the node's workers, background load)
into its own child cgroup (and every process born in a child: Ray's and Dask's
workers, ``ramps testbed experiment peers``), and every ``PERIOD`` seconds sets each child's
quota to its share of the robot under weighted processor sharing, as Linux
shares a real robot's cores::

    share = core * cost.weighted_shares(cores, weights of the busy children)
    core = quota / cores host cores

where the busy children are those that used CPU in the last period or are
runnable now (the busy loops of background load always are; an idle worker
is not; a program the kernel starved last period is) and a
child's weight is its process's CFS weight (``cost.nice_weight``): a worker
at nice 10 next to busy load at nice 0 gets what the load leaves, as on a
robot; at equal niceness this is ``core * min(1, cores / busy)``. Measured
on this kernel (cgroup v1), children of a throttled parent are scheduled
very unfairly, which is why the shares are computed here and not left to
the kernel, and why the busy children's quotas add up to at most what the
node leaves of the robot's: the node's own CPU (the robot's usage less its
children's, averaged over about a second, plus ``NODE_MARGIN`` of the
quota) is taken off first, as on a robot whose node at nice 0 runs before
its programs. Without that reserve, fifteen programs filling a robot of 4
emulated cores pushed it over its quota by the node's 3% and finished
spread over 85-126 s where processor sharing ends them together.

**A crowded robot has no caps.** Where no busy process's share exceeds half an
emulated core (``POOL_SHARE``: eight programs on four cores, or programs next to
eight busy processes), no cap would bind, and the
kernel shares one cgroup by CFS weight as it shares a real robot's cores. So
then the capper moves every process back into the robot's own cgroup and
removes the children ("pooled"), and caps again (the next period) when a share
exceeds that (programs end, a load stops). Capped, fifteen programs got 0.30-0.31 of the robot's
0.32 host cores (each child's quota a few percent off its share, the node's
reserve an estimate); pooled, the kernel gives the robot its whole quota, the
node takes what it uses and the programs share the rest fairly (measured:
0.62-0.68 CPU s each in 30 s, where sibling cgroups under the same throttled
parent got 0.02-1.00). The node's load sampler, walking one cgroup instead of
sixteen, costs less too. With a few programs to each host CPU the kernel is
not fair over seconds (which CPU's queue a program waits in decides its part):
five pooled programs on a robot of four cores ended 3.5-8.5 s after their start
where processor sharing ends them together after about 7 s; capped, with what
each is owed, within 0.9 s of each other (docs/lab/2026-11-28-sweep-pooling.md).

**Fair in the end.** The kernel does not hold the children of one robot to their
quotas evenly: a child's CPU time is handed out in slices that can outlast a
period, and a write of its quota refills it, so where the busy children's
quotas fill the robot the robot's own quota throttles them, and which of them
runs then is the kernel's choice. Measured with four programs on a robot of four
emulated cores, each child's quota 0.040-0.048 host cores: one got 0.063-0.070
over half-second windows, the newest 0.031-0.038, and ran 6.45 s where its
siblings took 4.78-5.27 (docs/lab/2026-11-27-fair-caps.md). So each busy child
is owed what its share gave it and it did not get, and its quota is its share
moved by what it is owed beyond the others, over ``OWED_HORIZON``: the one the
kernel favoured gets less until they are even.

The capper rereads the state file every period (robots restart after a crash
with new workers), and exits when the file is gone (``down``). Caps are
cgroup v1 only: on v2 a process may not stay in a cgroup whose children have
controllers, so the node would need a leaf of its own; robots on v2 run
without per-program caps.
"""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

from ramps.core.cost import nice_weight, weighted_shares
from ramps.runtime.measure import cgroup_usage, proc_cpu, proc_stat_fields

#: seconds between two share updates
PERIOD = 0.2
#: CFS period of a robot whose cgroup states none (and of its children), microseconds
CFS_PERIOD_US = 100_000
#: a child is busy when it used this fraction of its share in the last period
BUSY_FRACTION = 0.25
CHILD_PREFIX = "p"
#: of the robot's quota, kept free beyond the node's measured use (its use varies)
NODE_MARGIN = 0.005
#: weight of the latest period in the node's averaged use, and the most it may reserve
NODE_ALPHA = 0.2
NODE_MAX = 0.5
#: a child's quota is rewritten only when its share moved by more than this fraction,
#: or when the busy children's quotas together fall short of their shares by more than
#: ``QUOTA_SHORT`` (small steps down, each under the step, once left them up to 5% short)
QUOTA_STEP = 0.05
QUOTA_SHORT = 0.01
#: a robot is pooled when no busy process's share exceeds this fraction of a core: eight
#: programs on four cores (0.5 each), not five (0.8 each): pooled, the kernel ran five
#: programs on two host CPUs unevenly for seconds (one ended after 3.5 s, one after 8.5 s,
#: where processor sharing ends them together after 7), capped they ended within 0.9 s
POOL_SHARE = 0.5
#: a busy child owed CPU by the kernel gets its share and what it is owed over this many
#: seconds; what a child may be owed (or owe) is at most this many seconds of its share
OWED_HORIZON = 1.0
OWED_MAX = 0.5
#: seconds over which what a child is owed fades (what it lost under other neighbours)
OWED_DECAY = 10.0


def _is_node(pid: int) -> bool:
    """The node itself, or a process on its way to exec'ing it (a node that
    recover() just started is in the state file only a moment later), or the
    node's worker fork server: it stays in the robot's cgroup so that each
    worker it forks is born there and gets a cap of its own (moved with it,
    they would all share one)."""
    argv = _argv(pid)
    if argv is None:
        return True  # gone: nothing to move
    if b"--fork-server" in argv:  # the server, or a worker it forked (same argv): the worker's parent is the server
        rest = proc_stat_fields(pid)
        parent = _argv(int(rest[1])) if rest is not None else None
        return not (parent and b"--fork-server" in parent)
    return b"ramps.cli" in argv or (argv[0] or b"").rsplit(b"/", 1)[-1] in (b"sh", b"nsenter")


def _argv(pid: int) -> list[bytes] | None:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
    except OSError:
        return None


def shares(core: float, cores: int, busy: int) -> float:
    """Host cores each busy process gets at equal niceness: one emulated core
    while there are at most ``cores`` busy processes, an equal part beyond."""
    if busy <= cores:
        return core
    return core * cores / busy


def _full(cores: int, weights: list[float]) -> bool:
    """Whether busy processes of these CFS weights fill ``cores`` with no one's
    share above ``POOL_SHARE`` of a core (so no cap would bind, even where the
    kernel shares a little unevenly)."""
    return bool(weights) and max(weights) * cores <= POOL_SHARE * sum(weights)


def niceness(pid: int) -> int:
    """A process's niceness (0 if it is gone)."""
    rest = proc_stat_fields(pid)
    return 0 if rest is None else int(rest[16])


def _period(cpu: Path) -> int:
    """The CFS period of the robot's cgroup, microseconds (``CFS_PERIOD_US`` where unreadable)."""
    try:
        return int((cpu / "cpu.cfs_period_us").read_text())
    except (OSError, ValueError):
        return CFS_PERIOD_US


class RobotCaps:
    """The caps of one robot: its cgroup dirs (cpu, and cpuacct on v1)."""

    def __init__(self, cpu: Path, acct: Path | None, quota: float, cores: int) -> None:
        self.cpu, self.acct = cpu, acct
        #: the robot's CFS period (``Testbed(period_us=)``), its children's too
        self.period = _period(cpu)
        self.core = quota / cores
        self.cores = cores
        self._usage: dict[str, float] = {}  # CPU seconds of each child at the last tick
        self._quota: dict[str, int] = {}
        self._share: dict[str, float] = {}  # host cores of each child
        self._owed: dict[str, float] = {}  # CPU seconds each busy child's share gave it and it did not get
        self.share = self.core
        #: the robot's CPU seconds at the last tick, and its node's averaged use (host cores)
        self._robot_used: float | None = None
        self.node_use = 0.0
        #: every process is in the robot's own cgroup, uncapped (module docstring, "a full robot")
        self.pooled = False
        self._node_pid: int | None = None
        self._proc_used: dict[int, float] = {}  # CPU seconds of each pooled process at the last tick

    def children(self) -> list[str]:
        try:
            return sorted(p.name for p in self.cpu.iterdir() if p.is_dir() and p.name.startswith(CHILD_PREFIX))
        except OSError:
            return []

    def adopt(self, node_pid: int | None) -> int:
        """Move every process but the node from the robot's cgroup into a
        child of its own (none while the robot is pooled). Returns how many moved."""
        self._node_pid = node_pid
        if self.pooled:
            return 0
        moved = 0
        for pid in self._programs() + self._strays():
            name = f"{CHILD_PREFIX}{pid}"
            try:
                for base in (self.cpu, self.acct):
                    if base is None:
                        continue
                    (base / name).mkdir(exist_ok=True)
                (self.cpu / name / "cpu.cfs_period_us").write_text(str(self.period))
                (self.cpu / name / "cpu.cfs_quota_us").write_text(str(int(self.share * self.period)))
                # what it used before it moved in (a child made anew: nothing); ``tick`` counts from here
                self._usage.setdefault(name, cgroup_usage(self.cpu / name, self.acct / name if self.acct else None))
                for base in (self.cpu, self.acct):
                    if base is not None:
                        self._join(base / name, pid)
                moved += 1
            except OSError:  # it exited meanwhile
                continue
        return moved

    def _programs(self) -> list[int]:
        """The processes in the robot's own cgroup other than its node (and the
        node's fork server): programs' workers, background load."""
        try:
            pids = [int(p) for p in (self.cpu / "cgroup.procs").read_text().split()]
        except OSError:
            return []
        return [pid for pid in pids if pid != self._node_pid and not _is_node(pid)]

    def _strays(self) -> list[int]:
        """Processes born in another process's child cgroup: the workers a Ray raylet
        forks, the worker a Dask nanny spawns, a program's own subprocesses. Each is a
        busy process of its own on a robot, so each gets a child (and a cap) of its
        own too, as the workers ramps' fork server starts in the robot's cgroup do."""
        out = []
        for name in self.children():
            try:
                pids = (self.cpu / name / "cgroup.procs").read_text().split()
            except OSError:
                continue
            out += [int(p) for p in pids if f"{CHILD_PREFIX}{p}" != name]
        return out

    def _join(self, cgroup: Path, pid: int) -> None:
        """Move a process into a cgroup (the kernel takes it out of its old one)."""
        (cgroup / "cgroup.procs").write_text(str(pid))

    def _remove(self, cgroup: Path) -> None:
        try:
            cgroup.rmdir()
        except OSError:
            pass

    def _proc_cpu(self, pid: int) -> tuple[float, bool] | None:
        """(CPU seconds a process has used, whether it is runnable now), or None if gone."""
        got = proc_cpu(pid)
        return None if got is None else (got[0], got[1] == "R")

    def _runnable(self, pid: int) -> bool:
        """Whether the process is running or waiting for a CPU now: a program the
        kernel starves uses little of its share, and is busy all the same."""
        got = self._proc_cpu(pid)
        return got is not None and got[1]

    def _pool(self) -> None:
        """Every child's processes back into the robot's own cgroup, the children removed."""
        for name in self.children():
            for base in (self.cpu, self.acct):
                if base is None:
                    continue
                try:
                    pids = (base / name / "cgroup.procs").read_text().split()
                except OSError:
                    pids = []
                for pid in pids:
                    try:
                        self._join(base, int(pid))
                    except OSError:  # it exited meanwhile
                        pass
                self._remove(base / name)
        self._usage.clear()
        self._quota.clear()
        self._share.clear()
        self._owed.clear()
        self._proc_used = {pid: got[0] for pid in self._programs() if (got := self._proc_cpu(pid)) is not None}
        self.pooled = True

    def _pooled_busy(self, dt: float) -> list[int]:
        """The busy processes of a pooled robot: runnable now, or used a quarter
        of an equal share in the last period."""
        procs = self._programs()
        least = BUSY_FRACTION * self.core * min(1.0, self.cores / max(1, len(procs))) * dt
        busy, used = [], {}
        for pid in procs:
            got = self._proc_cpu(pid)
            if got is None:
                continue
            used[pid] = got[0]
            before = self._proc_used.get(pid)
            if got[1] or (before is not None and got[0] - before >= least):
                busy.append(pid)
        self._proc_used = used
        return busy

    def tick(self, dt: float) -> None:
        """Pool the robot when it is full, cap it again when it is not; while
        capped, drop empty children, find the busy ones, set every child's quota."""
        if self.pooled:
            weights = [nice_weight(niceness(pid)) for pid in self._pooled_busy(dt)]
            if _full(self.cores, weights):
                self._robot_used = None  # the node's use is not measured while pooled
                return
            self.pooled = False  # a share exceeds POOL_SHARE of a core: caps again, from now
            _, level = weighted_shares(self.cores, weights)
            self.share = self.core * min(1.0, level) if weights else self.core
            self.adopt(self._node_pid)
        busy: list[str] = []
        live = []
        got: dict[str, float] = {}  # CPU seconds of each live child since the last tick
        children_used = 0.0  # CPU seconds of the live children since the last tick
        for name in self.children():
            try:
                empty = not (self.cpu / name / "cgroup.procs").read_text().split()
            except OSError:
                empty = True
            if empty:
                for base in (self.cpu, self.acct):
                    if base is not None:
                        self._remove(base / name)
                self._usage.pop(name, None)
                self._quota.pop(name, None)
                self._share.pop(name, None)
                continue
            live.append(name)
            used = cgroup_usage(self.cpu / name, self.acct / name if self.acct else None)
            before = self._usage.get(name)
            self._usage[name] = used
            # from its usage at adoption (``adopt``): a new child's CPU since then is a program's,
            # not the node's (counted as the node's, each program a robot started took some of
            # its neighbours' reserve for a second or two)
            if before is not None:
                got[name] = used - before
                children_used += used - before
            # runnable counts from the first tick: children just adopted from a pool are busy at once
            if (before is not None and used - before >= BUSY_FRACTION * self._share.get(name, self.share) * dt) \
                    or self._runnable(int(name[len(CHILD_PREFIX):])):
                busy.append(name)
        robot_used = cgroup_usage(self.cpu, self.acct)
        if self._robot_used is not None and robot_used > 0.0:
            node = max(0.0, robot_used - self._robot_used - children_used) / dt
            self.node_use += NODE_ALPHA * (node - self.node_use)
        self._robot_used = robot_used
        weight = {name: nice_weight(niceness(int(name[len(CHILD_PREFIX):]))) for name in live}
        if _full(self.cores, [weight[n] for n in busy]):
            self._pool()
            return
        self._owe(busy, got, dt)
        parts, level = weighted_shares(self.cores, [weight[n] for n in busy])
        share = dict(zip(busy, parts))  # emulated cores of each busy child
        # a nice-0 newcomer's share, for children adopted before the next tick
        self.share = self.core * min(1.0, level) if busy else self.core
        for name in live:
            self._share[name] = self.core * share.get(name, min(1.0, weight[name] * level))
        # the busy children share what the node leaves of the robot (module docstring)
        quota = self.core * self.cores
        room = quota - min(self.node_use + NODE_MARGIN * quota, NODE_MAX * quota)
        total = sum(self._share[n] for n in busy)
        if total > room:
            for name in busy:
                self._share[name] *= room / total
        self._write_quotas(live, busy, quota, room, crowded=total > room)

    def _owe(self, busy: list[str], got: dict[str, float], dt: float) -> None:
        """What each busy child is owed: the CPU seconds its share gave it since the last tick
        less what it got, summed while it stays busy and fading over ``OWED_DECAY`` (within
        ``OWED_MAX`` seconds of its share). Children that stop being busy are owed nothing."""
        owed = {}
        for name in busy:
            share = self._share.get(name)
            if share and name in got:
                limit = OWED_MAX * share
                kept = self._owed.get(name, 0.0) * max(0.0, 1.0 - dt / OWED_DECAY)
                owed[name] = max(-limit, min(limit, kept + share * dt - got[name]))
        self._owed = owed

    def _targets(self, busy: list[str], room: float, crowded: bool) -> dict[str, float]:
        """Host cores each busy child's quota is set to: its share, and where the busy children
        fill what the node leaves (``crowded``), more for one owed more than the others (in
        seconds of its own share), less for one owed less, over about ``OWED_HORIZON`` seconds;
        together at most ``room``. The kernel does not hold children of one throttled robot to
        their quotas evenly (module docstring, "fair in the end"); where the robot's quota does
        not bind, each child's own does, and a quota rewritten more often only overruns more."""
        if not crowded:
            return {n: self._share[n] for n in busy}
        rel = {n: self._owed.get(n, 0.0) / self._share[n] for n in busy if self._share[n] > 0}
        mean = sum(rel.values()) / len(rel) if rel else 0.0
        out = {n: self._share[n] * max(1 - OWED_MAX, min(1 + OWED_MAX, 1 + (rel.get(n, mean) - mean) / OWED_HORIZON))
               for n in busy}
        total = sum(out.values())
        return {n: v * room / total for n, v in out.items()} if total > room else out

    def _write_quotas(self, live: list[str], busy: list[str], quota: float, room: float, *, crowded: bool) -> None:
        """Every live child's quota: a busy one's target (``_targets``), an idle one's share."""
        target = self._targets(busy, room, crowded)
        # the busy children's quotas as they stand: over what the node leaves, the robot's
        # own quota throttles and the kernel starves some of them (the margin is the slack
        # between where they are set and where they must be rewritten)
        given = sum(self._quota.get(n, 0) for n in busy)
        over = given > (quota - self.node_use) * self.period
        short = given < sum(target.values()) * (1 - QUOTA_SHORT) * self.period
        for name in live:
            q = max(1000, int(target.get(name, self._share[name]) * self.period))
            old = self._quota.get(name)
            # a write refills the child's runtime at once: rewriting a quota every tick for
            # small changes let programs overrun theirs by a third (and the robot's quota with them)
            if old is None or abs(q - old) > QUOTA_STEP * old or (over and q < old) or (short and q > old):
                try:
                    (self.cpu / name / "cpu.cfs_quota_us").write_text(str(q))
                    self._quota[name] = q
                except OSError:
                    pass


def run(state_file: Path) -> None:
    """The capper's loop: until the testbed's state file is gone."""
    caps: dict[str, RobotCaps] = {}
    last = time.monotonic()
    while True:
        try:
            state = json.loads(state_file.read_text())
        except FileNotFoundError:
            return
        except (OSError, ValueError):  # being rewritten
            time.sleep(PERIOD / 4)
            continue
        now = time.monotonic()
        dt, last = max(now - last, 1e-3), now
        quota = float(state["quota"])
        cores = int(state.get("cores") or max(1, int(quota + 0.5)))  # as the node's detect_cores
        for rb in state["robots"]:
            name = rb["name"]
            dirs = [Path(d) for d in rb.get("cgroup") or []]
            if not dirs:
                continue
            cpu = next((d for d in dirs if "cpuacct" not in d.parts), dirs[0])
            acct = next((d for d in dirs if "cpuacct" in d.parts), None)
            rc = caps.get(name)
            if rc is None or rc.cpu != cpu:
                rc = caps[name] = RobotCaps(cpu, acct, quota, cores)
            try:
                rc.adopt(rb.get("pid"))
                rc.tick(dt)
            except Exception as exc:  # keep capping the other robots; the log says why
                print(f"caps of {name}: {type(exc).__name__}: {exc}", file=sys.stderr, flush=True)
        time.sleep(PERIOD)


def main(argv: list[str] | None = None) -> None:
    args = sys.argv[1:] if argv is None else argv
    if len(args) != 1:
        print("usage: python -m ramps.testbed.caps STATE_FILE  (started by the testbed itself)", file=sys.stderr)
        raise SystemExit(2)
    try:
        os.nice(-5)  # the shares must keep up with busy robots
    except OSError:
        pass
    run(Path(args[0]))


if __name__ == "__main__":
    main()
