"""The checkpoint API of programs: ``ramps.checkpoint(state)`` inside a
worker reaches the pool (and from there the host's core), ``ramps.resume()``
gives a restarted program its saved state; bad state is a clear error."""

from __future__ import annotations

import os
import threading
from pathlib import Path

import msgspec
import pytest

import ramps
from ramps.core.messages import MAX_CHECKPOINT_BYTES
from ramps.runtime.workers import WorkerPool

TESTS = str(Path(__file__).parent)


def test_outside_a_worker_checkpoint_checks_and_does_nothing_and_resume_is_none():
    assert ramps.checkpoint({"i": 3}) is False
    assert ramps.checkpoint(b"raw") is False
    assert ramps.resume() is None
    with pytest.raises(ValueError, match=f"exceeds the limit of {MAX_CHECKPOINT_BYTES} bytes"):
        ramps.checkpoint(b"x" * MAX_CHECKPOINT_BYTES)
    with pytest.raises(TypeError, match="a checkpoint is bytes or a value msgspec can encode"):
        ramps.checkpoint(object())


def _pool(programs: dict[str, str]) -> tuple[WorkerPool, dict, list, threading.Event]:
    """A started one-worker pool: results decoded into ``done`` by key (``ev`` set on each),
    checkpoints appended to ``saved`` as (key, state, fraction)."""
    done: dict = {}
    saved: list = []
    ev = threading.Event()

    def finished(key, ok, value, error, retryable, cpu_s=None, died=False):
        done[key] = msgspec.msgpack.decode(value) if ok else error
        ev.set()

    env = dict(os.environ, PYTHONPATH=os.pathsep.join([TESTS, os.environ.get("PYTHONPATH", "")]))
    pool = WorkerPool(1, programs, finished, env=env,
                      on_checkpoint=lambda key, state, fraction: saved.append((key, state, fraction)))
    pool.start()
    return pool, done, saved, ev


@pytest.mark.slow
def test_a_worker_sends_checkpoints_and_a_restart_resumes_from_one():
    pool, done, saved, ev = _pool({"resumable": "e2eprogs:resumable"})
    try:
        pool.run(("p", 1), "resumable", msgspec.msgpack.encode({"steps": 3, "dt": 0.25}))
        assert ev.wait(30), "no result"
        assert done[("p", 1)]["first"] == 0
        assert [msgspec.msgpack.decode(s) for _, s, _ in saved] == [{"i": 1}, {"i": 2}, {"i": 3}]
        assert [f for _, _, f in saved] == pytest.approx([1 / 3, 2 / 3, 1.0])
        ev.clear()
        pool.run(("p", 2), "resumable", msgspec.msgpack.encode({"steps": 3, "dt": 0.05}), saved[1][1])
        assert ev.wait(30), "no result"
        assert done[("p", 2)]["first"] == 2
    finally:
        pool.stop()


@pytest.mark.slow
def test_a_burn_resumed_from_its_checkpoint_ends_with_the_uninterrupted_checksum():
    from ramps.programs.burn import burn

    pool, done, saved, ev = _pool({"burn": "ramps.programs.burn:burn"})
    try:
        args = msgspec.msgpack.encode({"units": 0.05, "checkpoint_every": 0.01})
        pool.run(("b", 1), "burn", args)
        assert ev.wait(30), "no result"
        whole = done[("b", 1)]
        assert whole["checksum"] == burn(units=0.05)["checksum"] and whole["resumed_at"] == 0
        assert saved, "a burn of 5 checkpoints sent none"
        _, state, fraction = saved[-1]
        place = msgspec.msgpack.decode(state)
        assert 0 < place["done"] < whole["iterations"] and fraction == pytest.approx(place["done"] / whole["iterations"])
        ev.clear()
        pool.run(("b", 2), "burn", args, state)  # a move or a restart: the worker is handed the saved place
        assert ev.wait(30), "no result"
        assert done[("b", 2)]["resumed_at"] == place["done"] and done[("b", 2)]["checksum"] == whole["checksum"]
    finally:
        pool.stop()
