"""A worker process: ``python -m ramps.runtime.worker``.

How this works: the executor starts one of these per running program (at
least one per core, see ``ramps.runtime.workers``). It reads frames
from stdin and writes frames to a private copy of its stdout (fd 1 itself is
pointed at stderr, so a program's ``print`` cannot corrupt the protocol). A
frame (``ramps.runtime.frames``) is a 4-byte big-endian length and a msgpack
body:

    first frame in:   {"targets": {name: "module:function", ...}, "nice": n}
    each job in:      [program, args_bytes] or [program, args_bytes, resume_bytes]
                      or [program, args_bytes, resume_bytes or None, grant]
                      (the accelerator granted, ``ramps.accelerator()``)
    each reply out:   [ok, value_bytes, error_text, cpu_seconds] (the CPU the
                      program used: the worker's own, threads and waited-for
                      children such as an executable included)
    progress out:     {"progress": fraction, "detail": text}  (any number
                      before the reply; from ``ramps.progress`` or an
                      executable's ``RAMPS_PROGRESS`` stderr lines)
    checkpoint out:   {"checkpoint": state_bytes, "fraction": f | None}
                      (``ramps.checkpoint``; ``resume_bytes`` is the latest
                      one of an earlier attempt, ``ramps.resume()`` decodes it)

Nothing is pickled. The worker runs one program at a time and exits when
stdin closes; what the program reaches of it (progress, checkpoints, its
resume state) is ``ramps.runtime.running``. ``python -m ramps.runtime.worker
--fork-server`` is the executor's fork server (``ramps.runtime.forkserver``),
whose forked children run ``run`` over pipes of their own.
"""

from __future__ import annotations

import faulthandler
import os
import resource
import sys
import time
import traceback
from typing import Any, BinaryIO, Callable

import msgspec

from ramps.runtime import running
from ramps.runtime.frames import read_frame

_enc = msgspec.msgpack.Encoder()
_dec = msgspec.msgpack.Decoder()


def _cpu_seconds() -> float:
    """CPU seconds this worker and its waited-for children have used, to
    the microsecond (``os.times`` counts clock ticks: a call of a few
    milliseconds measured 0)."""
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + children.ru_utime + children.ru_stime


def run(inp: BinaryIO, out: BinaryIO) -> None:
    """Run jobs from ``inp``, one at a time, each reply a frame on ``out``,
    until ``inp`` ends."""
    from ramps.runtime.command import CommandFailed
    from ramps.runtime.registry import decode_args, resolve

    first = read_frame(inp)
    if first is None:
        return
    faulthandler.enable()  # a crash in C (SIGSEGV, SIGABRT...) leaves its Python traceback on stderr
    init = _dec.decode(first)
    targets: dict[str, str] = init["targets"]
    if init.get("nice"):  # programs yield to the node (heartbeats) and the robot's own software
        os.nice(int(init["nice"]))
    fns: dict[str, Callable[..., Any]] = {}
    while True:
        body = read_frame(inp)
        if body is None:
            return
        job = _dec.decode(body)
        program, args = job[0], job[1]
        running.begin(out, job[2] if len(job) > 2 else None, job[3] if len(job) > 3 else None)
        cpu0: float | None = None
        try:
            fn = fns.get(program)
            if fn is None:
                fn = fns[program] = resolve(targets[program])
            kwargs = decode_args(args)
            cpu0 = _cpu_seconds()
            value = fn(**kwargs)
            try:
                data = _enc.encode(value)
                reply = [True, data, ""]
                if len(data) > running.MAX_RESULT_BYTES:
                    reply = [False, b"", f"program {program!r} returned {len(data)} bytes; results are limited to "
                                         f"{running.MAX_RESULT_BYTES} bytes (send a path or split the work)"]
            except (TypeError, msgspec.EncodeError) as exc:
                reply = [False, b"", f"program {program!r} returned a value that cannot be sent: {exc}"]
        except CommandFailed as exc:  # an executable's failure: its own words, exit code and stderr
            reply = [False, b"", str(exc)[:3500]]
        except SystemExit as exc:  # the program's own end: an error like any other, not a dead worker
            reply = [False, b"", f"program {program!r} called sys.exit({exc.code!r})"]
        except Exception as exc:  # the program's own failure, reported to its origin
            tb = traceback.format_exception(type(exc), exc, exc.__traceback__)
            reply = [False, b"", "".join(tb[-6:])[-3000:]]
        reply.append(None if cpu0 is None else round(max(0.0, _cpu_seconds() - cpu0), 6))
        running.end(out, _enc.encode(reply))


def main() -> None:
    if sys.argv[1:2] == ["--fork-server"]:  # the executor's fork server (ramps.runtime.forkserver)
        from ramps.runtime.forkserver import main as serve

        serve(int(sys.argv[2]), int(sys.argv[3]), run)
        return
    proto_out = os.fdopen(os.dup(1), "wb", buffering=0)
    os.dup2(2, 1)  # prints from programs go to stderr
    sys.stdout = sys.stderr
    try:
        run(sys.stdin.buffer, proto_out)
    except (BrokenPipeError, KeyboardInterrupt):
        pass


if __name__ == "__main__":
    main()
