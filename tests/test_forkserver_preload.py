"""The executor's fork server imports every program's module, and the
modules a program names in ``preload`` (``route_plan``: OR-Tools), before it
forks a worker: a fresh worker's first call pays no import. A module that
fails to import there does not stop the pool; its program's runs fail with
the import's error."""

from __future__ import annotations

import os
import threading
from pathlib import Path

import msgspec
import pytest

from ramps.errors import ConfigError
from ramps.runtime.registry import BUILTINS, program
from ramps.runtime.workers import WorkerPool

TESTS = str(Path(__file__).parent)


def run_all(targets: dict[str, str], jobs: list[tuple[str, dict]], bundled: bool = True) -> list[tuple[bool, object]]:
    """Run ``jobs`` (program, kwargs), one after another, on a fresh pool of one worker
    (``bundled``: its fork server preloads the bundled programs' modules too)."""
    done: dict = {}
    ev = threading.Event()

    def finished(key, ok, value, error, retryable, *_):
        done[key] = (ok, msgspec.msgpack.decode(value) if ok else error)
        ev.set()

    env = dict(os.environ, PYTHONPATH=os.pathsep.join([TESTS, os.environ.get("PYTHONPATH", "")]))
    pool = WorkerPool(1, targets, finished, env=env, bundled=bundled)
    pool.start()
    try:
        for i, (prog, kwargs) in enumerate(jobs):
            ev.clear()
            pool.run((prog, i), prog, msgspec.msgpack.encode(kwargs))
            assert ev.wait(60), f"{prog} did not finish"
        assert pool.forked == 1 and pool.died == 0  # one worker, forked, ran every job
    finally:
        pool.stop()
    return [done[(prog, i)] for i, (prog, _) in enumerate(jobs)]


@pytest.mark.slow
def test_a_fresh_worker_has_every_programs_module_and_preloads_before_its_first_call():
    targets = {"route_plan": BUILTINS["route_plan"].target, "modules": "preloadprogs:modules",
               "lazy": "preloadprogs:lazy", "missing": "preloadprogs:missing", "broken": "preloadprogs_broken:plan"}
    names = ["ramps.programs.route", "ortools.sat.python.cp_model", "preloadprogs_lazy"]
    [(ok, seen), lazy, missing, broken, (ok2, _)] = run_all(
        targets, [("modules", {"names": names}), ("lazy", {}), ("missing", {}), ("broken", {}),
                  ("modules", {"names": names})])
    # the first call of a fresh worker: the modules are there already
    assert ok and seen == dict.fromkeys(names, True), seen
    assert lazy == (True, "lazy")
    # a preload or a module that failed to import: the pool served on, and the runs say why
    assert not missing[0] and "preloadprogs_no_such_module" in missing[1], missing
    assert not broken[0] and "the map server is not configured" in broken[1], broken
    assert ok2


@pytest.mark.slow
def test_a_node_not_told_to_preload_the_bundled_programs_imports_only_its_own_programs_modules():
    """The node's default (``preload_bundled`` off): route_plan's OR-Tools, about 70 MiB
    resident, is not in the fork server, so a worker's first route_plan call imports it;
    a registered program's own ``preload`` still is."""
    from ramps.runtime.settings import load_settings

    assert load_settings(flags={"robot": "r1"}, environ={}).preload_bundled is False
    assert load_settings(flags={"robot": "r1"}, environ={"RAMPS_PRELOAD_BUNDLED": "1"}).preload_bundled
    targets = {"route_plan": BUILTINS["route_plan"].target, "modules": "preloadprogs:modules",
               "lazy": "preloadprogs:lazy"}
    names = ["ramps.programs.route", "ortools.sat.python.cp_model", "preloadprogs_lazy"]
    [(ok, seen), (ok2, plan), (ok3, after)] = run_all(
        targets, [("modules", {"names": names}), ("route_plan", {"picks": 3}), ("modules", {"names": names})],
        bundled=False)
    assert ok and seen == {"ramps.programs.route": True, "ortools.sat.python.cp_model": False,
                           "preloadprogs_lazy": True}, seen
    assert ok2, plan  # the first call imports it, and runs
    assert ok3 and after["ortools.sat.python.cp_model"]


def test_preload_is_a_list_of_module_names():
    for bad in ("torch", ["torch", ""], [3]):
        with pytest.raises(ConfigError, match="preload is a list of module names"):
            program("p", preload=bad)
