"""Frames between the worker pool and its workers over unbuffered pipes
(ramps.runtime.frames.read_frame): arguments and results larger than a
pipe's 64 KiB arrive whole. Before, one read returned what the pipe held,
the frame looked cut short, and every program with 100 kB of parameters
died under its worker on every robot (found by the testbed's slow-link
experiment: 98 placements of one program)."""

from __future__ import annotations

import os
import threading

import msgspec
import pytest

from ramps.runtime.frames import frame, read_frame


@pytest.mark.parametrize("size", [0, 10, 65_536, 1_000_000])
def test_a_frame_larger_than_the_pipe_arrives_whole_on_an_unbuffered_stream(size: int) -> None:
    r, w = os.pipe()
    body = os.urandom(size)
    writer = threading.Thread(target=lambda: (os.write(w, frame(body)[:3]), _write_all(w, frame(body)[3:]),
                                              os.close(w)))
    writer.start()
    with os.fdopen(r, "rb", buffering=0) as stream:
        assert read_frame(stream) == body
        assert read_frame(stream) is None  # end of stream
    writer.join()


def test_a_frame_cut_short_by_its_writer_is_none() -> None:
    r, w = os.pipe()
    os.write(w, frame(b"x" * 100)[:50])
    os.close(w)
    with os.fdopen(r, "rb", buffering=0) as stream:
        assert read_frame(stream) is None


def _write_all(fd: int, data: bytes) -> None:
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view):]


@pytest.mark.slow
def test_a_program_with_a_megabyte_of_parameters_and_result_runs_in_a_forked_worker() -> None:
    from ramps.runtime.workers import WorkerPool

    done: dict = {}
    ev = threading.Event()

    def finished(key, ok, value, error, retryable, cpu_s=None, died=False):
        done[key] = (ok, msgspec.msgpack.decode(value) if ok else error)
        ev.set()

    pool = WorkerPool(1, {"echo": "ramps.programs.burn:echo"}, finished)
    pool.start()
    try:
        data = os.urandom(1_000_000)
        pool.run(("p", 1), "echo", msgspec.msgpack.encode({"data": data}))
        assert ev.wait(60), "no outcome"
        ok, value = done[("p", 1)]
        assert ok, value
        assert value["data"] == data
    finally:
        pool.stop()
