"""A program that kills its own worker is a poison pill: its origin stops
placing it after a small bound, and its error says how each attempt ended.

The executor's side (real processes): a worker that dies by itself is
reported with its exit code or signal and the last lines of its stderr, as
the fork server saw them, and marked ``died``; a program's ``sys.exit`` is
its own error, not a dead worker."""

from __future__ import annotations

import os
import threading
from pathlib import Path

import msgspec
import pytest

from ramps.runtime.workers import WorkerPool

TESTS = str(Path(__file__).parent)
POISON = {n: f"poison_progs:{n}" for n in ("exits", "segfaults", "kills_itself", "quits", "fine")}


def _pool_run(jobs: list[tuple[str, dict]]) -> dict:
    done: dict = {}
    all_done = threading.Event()

    def finished(key, ok, value, error, retryable, cpu_s=None, died=False):
        done[key[0]] = (ok, error, retryable, died)
        if len(done) == len(jobs):
            all_done.set()

    env = dict(os.environ, PYTHONPATH=os.pathsep.join([TESTS, os.environ.get("PYTHONPATH", "")]))
    pool = WorkerPool(1, POISON, finished, env=env)
    pool.start()
    try:
        for name, kw in jobs:
            pool.run((name, 1), name, msgspec.msgpack.encode(kw))
        assert all_done.wait(30), done
    finally:
        pool.stop()
    return done


@pytest.mark.slow
def test_a_worker_that_dies_by_itself_is_reported_with_how_it_ended():
    done = _pool_run([("exits", {"code": 3, "say": "opening the map\nmap file is corrupt"}),
                      ("segfaults", {}), ("kills_itself", {}), ("quits", {"code": 4}), ("fine", {"x": 5})])
    ok, error, retryable, died = done["exits"]
    assert (ok, retryable, died) == (False, True, True)
    assert "exit code 3" in error and "map file is corrupt" in error, error
    ok, error, retryable, died = done["segfaults"]
    assert (retryable, died) == (True, True)
    assert "signal 11 (SIGSEGV)" in error and "in segfaults" in error, error  # faulthandler's traceback
    assert "forkserver.py" not in error  # ramps's own frames left out
    assert done["kills_itself"][2:] == (True, True) and "signal 9 (SIGKILL)" in done["kills_itself"][1]
    # sys.exit is the program's own error: not retried, its worker lives on
    assert done["quits"] == (False, "program 'quits' called sys.exit(4)", False, False)
    assert done["fine"][0] is True
