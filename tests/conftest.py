"""Shared test set-up.

* ``tests/`` is on ``sys.path`` so test modules share helpers
  (``tests/corehelpers.py``, ``tests/runtime_team.py``) without a package.
* Running in parallel (``make test``: pytest-xdist, ``-n 3 --dist
  loadfile``): each test module runs on one worker, so a team or testbed
  that a module's tests share (a module-scoped fixture) starts once.
  (``--dist loadgroup`` would spread the rest one by one, but with pytest
  9.2 xdist 3.8 cannot tag test ids with their group, so it ignores the
  groups.) Tests marked ``serial`` (they measure CPU, or run emulated robots
  whose timing assertions need the CPU they were given) are left out of the
  parallel pass: ``make test`` runs them afterwards, alone. Modules with
  the most slow tests are collected first, so the workers start on them.
* ``--cpu-report FILE``: for every test, its wall time and the CPU time it
  cost (this process plus every child it waited for: nodes, workers, CLI
  runs, a testbed's robots), written to ``FILE`` as JSON at the end. It tells
  a test that waits (CPU far below wall) from one that computes, which is
  what decides whether running it beside others (pytest-xdist, ``make
  test``) saves time. With xdist, each worker writes ``FILE.<worker>``.
"""

from __future__ import annotations

import atexit
import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import pytest

# let test modules share helpers (tests/corehelpers.py) without a package
sys.path.insert(0, str(Path(__file__).parent))
# every node a test starts keeps its durable record (ramps.runtime.store) in a
# folder of this run, not in the user's ~/.local/state/ramps; removed at the end
_STATE_DIR = tempfile.mkdtemp(prefix="ramps-test-state-")
os.environ.setdefault("RAMPS_STATE_DIR", _STATE_DIR)
atexit.register(shutil.rmtree, _STATE_DIR, True)

_CPU_REPORT: list[dict[str, object]] = []


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--cpu-report", metavar="FILE", default=None,
                     help="write each test's wall and CPU seconds (with its reaped children) to FILE as JSON")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Modules with the most slow tests first, each kept whole (the order of
    the rest unchanged): xdist hands modules out in this order, so the long
    ones start at once and the fast ones fill the gaps at the end, instead of
    the e2e modules (late in the alphabet) starting last and running alone."""
    slow: dict[Path, int] = {}
    for item in items:
        slow[item.path] = slow.get(item.path, 0) + (item.get_closest_marker("slow") is not None)
    rank = {path: i for i, path in enumerate(sorted(slow, key=lambda p: -slow[p]))}
    items.sort(key=lambda item: rank[item.path])


def _cpu() -> float:
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None):
    if not item.config.getoption("--cpu-report"):
        yield
        return
    wall, cpu = time.monotonic(), _cpu()
    yield
    _CPU_REPORT.append({"test": item.nodeid, "wall_s": round(time.monotonic() - wall, 2),
                        "cpu_s": round(_cpu() - cpu, 2)})


def pytest_sessionfinish(session: pytest.Session) -> None:
    path = session.config.getoption("--cpu-report")
    if not path or not _CPU_REPORT:
        return
    worker = os.environ.get("PYTEST_XDIST_WORKER")
    out = Path(f"{path}.{worker}" if worker else path)
    out.write_text(json.dumps(sorted(_CPU_REPORT, key=lambda r: -float(r["wall_s"])), indent=1))  # type: ignore[arg-type]
