"""Clearing a host of testbeds, including what crashed runs left behind.

How this works: every testbed writes its state file (``/run/ramps`` by
default) before it creates anything, so ``down_all`` first takes down each
testbed it finds there (``Testbed.attach(...).down()``), then sweeps what no
state file names any more: processes in ``ramps-*`` namespaces and in
``ramps-t<N>-*`` cgroups, those cgroups, ``caps`` processes whose testbed
is gone, ``ramps-*`` namespaces and ``rb-*`` links. ``leftovers`` lists what
``down_all`` would remove (empty on a clean host).

Rules: root only. Only testbed names are touched: ``ramps-t<N>-*`` cgroups
(a ``LocalTeam``'s ``ramps-e2e-*`` cgroups of a test running beside are
left alone). ``down_all`` removes every testbed on the host, other people's
included; a test cleans up its own with ``Testbed.down()``.
"""

from __future__ import annotations

import os
import re
import signal
import time
from pathlib import Path

from ramps.runtime.localteam import CG_ROOT
from ramps.testbed import net
from ramps.testbed.bed import STATE_DIR, Testbed
from ramps.testbed.procs import TestbedError, _cgroup, _cgroup_pids, _signal_all

_TB_CGROUP = re.compile(r"ramps-t\d+-\w+")


def down_all(state_dir: Path | None = None) -> list[str]:
    """Remove every testbed on this host, including leftovers of crashed runs:
    processes in testbed cgroups and namespaces, ``ramps-t<N>-*`` cgroups,
    ``ramps-*`` namespaces, ``rb-*`` links, state files. Returns what went."""
    net.need_root()
    gone: list[str] = []
    d = Path(state_dir or STATE_DIR)
    for f in sorted(d.glob("testbed-*.json")):
        try:
            Testbed.attach(f.stem.removeprefix("testbed-"), state_dir=d).down()
            gone.append(f"testbed {f.stem.removeprefix('testbed-')}")
        except (TestbedError, ValueError, KeyError, OSError):
            f.unlink(missing_ok=True)
    dirs = []
    for sub in ("cpu", "cpuacct", ""):
        base = CG_ROOT / sub if sub else CG_ROOT
        if base.is_dir():
            dirs += [p for p in base.iterdir() if p.is_dir() and _TB_CGROUP.fullmatch(p.name)]
    for pid, tb in _capper_pids():  # a capper whose testbed's state file is gone
        _signal_all([pid], signal.SIGKILL)
        gone.append(f"caps process {pid} of testbed-{tb}")
    for ns in net.namespaces():
        if ns.startswith(net.NS_PREFIX):
            _signal_all(net.netns_pids(ns), signal.SIGKILL)
    for _ in range(20):
        pids = _cgroup_pids([str(p) for p in dirs])
        if not pids:
            break
        _signal_all(pids, signal.SIGKILL)
        time.sleep(0.05)
    for p in dirs:
        mode = "v2" if p.parent == CG_ROOT else "v1"
        _cgroup([str(p)], mode).remove()
        if not p.exists():
            gone.append(f"cgroup {p}")
    gone += net.sweep()
    for f in d.glob("testbed-*.tmp"):
        f.unlink(missing_ok=True)
    return gone


def leftovers() -> list[str]:
    """What ``down_all`` would remove (empty when the host is clean)."""
    found = [f"namespace {ns}" for ns in net.namespaces() if ns.startswith(net.NS_PREFIX)]
    found += [f"link {name}" for name in net.links() if name.startswith(net.LINK_PREFIX)]
    for sub in ("cpu", "cpuacct", ""):
        base = CG_ROOT / sub if sub else CG_ROOT
        if base.is_dir():
            found += [f"cgroup {p}" for p in base.iterdir() if p.is_dir() and _TB_CGROUP.fullmatch(p.name)]
    found += [f"caps process {pid} of testbed-{tb}" for pid, tb in _capper_pids()]
    return found


def _capper_pids() -> list[tuple[int, str]]:
    """(pid, testbed id) of processes running ``ramps.testbed.caps``."""
    out = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit() and int(d.name) != os.getpid():
            try:
                argv = (d / "cmdline").read_bytes().split(b"\0")
            except OSError:
                continue
            if b"ramps.testbed.caps" in argv:  # ... -m ramps.testbed.caps <state dir>/testbed-<tb>.json
                after = argv[argv.index(b"ramps.testbed.caps") + 1:]
                state = Path(os.fsdecode(after[0])) if after else Path()
                out.append((int(d.name), state.stem.removeprefix("testbed-")))
    return out
