"""The worker pool's monitor thread is woken when programs start to wait,
or when a worker took one while others wait, not for every program queued
behind them (a burst used to wake it once a program); programs that wait
still get new workers after ``GROW_AFTER``, and all of them run."""

from __future__ import annotations

import pytest

from test_workers import args, make_pool, wait_until

# real worker processes
pytestmark = pytest.mark.slow


def test_programs_queued_behind_waiting_ones_do_not_wake_the_monitor():
    pool, done = make_pool(1, max_size=1)  # one worker, never more: the rest wait
    pokes: list[int] = []
    poke = pool._poke
    pool._poke = lambda: (pokes.append(1), poke())[1]  # type: ignore[method-assign]
    try:
        pool.run(("a", 1), "sleepy", args(seconds=0.3, tag="a"))  # takes the worker: none waits
        assert pokes == []
        for i in range(6):
            pool.run((f"q{i}", 1), "sleepy", args(seconds=0.01, tag=f"q{i}"))
        assert len(pokes) == 1  # when the first started to wait
        assert wait_until(lambda: len(done) == 7, 20), done
        assert all(ok for ok, _, _ in done.values())
        assert len(pool._workers) == 1
    finally:
        pool.stop()


def test_waiting_programs_still_get_new_workers():
    pool, done = make_pool(1)
    try:
        for i in range(4):
            pool.run((f"p{i}", 1), "sleepy", args(seconds=1.0, tag=f"p{i}"))
        # four programs on one core: the monitor starts a worker for each that waits GROW_AFTER
        assert wait_until(lambda: pool.busy() == 4, 10), pool.pids()
        assert pool.queued() == 0
        assert wait_until(lambda: len(done) == 4, 20), done
    finally:
        pool.stop()
