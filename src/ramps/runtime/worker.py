"""A worker process: ``python -m ramps.runtime.worker``.

How this works: the executor starts one of these per running program (at
least one per core, see ``ramps.runtime.workers``). It reads frames
from stdin and writes frames to a private copy of its stdout (fd 1 itself is
pointed at stderr, so a program's ``print`` cannot corrupt the protocol). A
frame is a 4-byte big-endian length and a msgpack body:

    first frame in:   {"targets": {name: "module:function", ...}, "nice": n}
    each job in:      [program, args_bytes] or [program, args_bytes, resume_bytes]
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
stdin closes.
"""

from __future__ import annotations

import faulthandler
import math
import os
import struct
import sys
import threading
import time
import traceback
from typing import Any, BinaryIO, Callable

import msgspec

_enc = msgspec.msgpack.Encoder()
_dec = msgspec.msgpack.Decoder()
_LEN = struct.Struct(">I")


def _read_exactly(stream: BinaryIO, n: int) -> bytes:
    """``n`` bytes, or fewer at end of stream. The pipes of forked workers are
    unbuffered (``buffering=0``), where one ``read`` returns at most what the
    pipe holds (64 KiB): arguments or results beyond that were cut short, and
    the worker or the pool took the short frame for a dead peer."""
    data = stream.read(n)
    if data is None or len(data) == n:
        return data or b""
    parts = [data]
    got = len(data)
    while got < n:
        more = stream.read(n - got)
        if not more:
            break
        parts.append(more)
        got += len(more)
    return b"".join(parts)


def read_frame(stream: BinaryIO) -> bytes | None:
    head = _read_exactly(stream, 4)
    if len(head) < 4:
        return None
    (n,) = _LEN.unpack(head)
    body = _read_exactly(stream, n)
    return body if len(body) == n else None


def frame(body: bytes) -> bytes:
    return _LEN.pack(len(body)) + body


#: at most one progress frame per this many seconds (the last one is never lost
#: for long: the host forwards the newest with its next heartbeat anyway)
PROGRESS_MIN_INTERVAL = 0.05
#: longest progress text sent
PROGRESS_TEXT = 200
_progress_lock = threading.Lock()
_progress_out: BinaryIO | None = None
_progress_sent = 0.0


def report_progress(fraction: float, detail: str = "") -> bool:
    """Tell the caller how far the running program is (0..1, clamped).

    Inside a worker the value travels to the program's origin and its
    caller; anywhere else (a program called directly, in a test) it does
    nothing. Returns whether it was sent. Cheap enough to call in a loop:
    calls closer together than PROGRESS_MIN_INTERVAL are dropped, except 1.0."""
    global _progress_sent, _progress_last
    out = _progress_out
    if out is None:
        return False
    try:
        f = float(fraction)
    except (TypeError, ValueError):
        raise TypeError(f"progress is a number between 0 and 1, not {fraction!r}") from None
    if not math.isfinite(f):
        raise ValueError(f"progress is a number between 0 and 1, not {fraction!r}")
    f = min(1.0, max(0.0, f))
    now = time.monotonic()
    with _progress_lock:
        if now - _progress_sent < PROGRESS_MIN_INTERVAL and f < 1.0:
            return False
        _progress_sent = now
        _progress_last = f
        out.write(frame(_enc.encode({"progress": f, "detail": str(detail)[:PROGRESS_TEXT]})))
        out.flush()
    return True


#: at most one checkpoint per this many seconds (a program may call it in a loop)
CHECKPOINT_MIN_INTERVAL = 0.2
_checkpoint_sent = -float("inf")
#: the newest progress the running program reported (sent with its checkpoints)
_progress_last: float | None = None
#: the running program's resume state (msgpack), None on a fresh start
_resume: bytes | None = None


def encode_checkpoint(state: Any) -> bytes:
    """A program's state as a checkpoint travels: msgpack, at most
    MAX_CHECKPOINT_BYTES (``bytes`` stay bytes, anything else msgspec can
    encode comes back as its plain msgpack form)."""
    from ramps.core.messages import MAX_CHECKPOINT_BYTES

    try:
        data = _enc.encode(state)
    except (TypeError, msgspec.EncodeError) as exc:
        raise TypeError(f"a checkpoint is bytes or a value msgspec can encode (dict, list, str, numbers, "
                        f"Structs...), not {type(state).__name__}: {exc}") from None
    if len(data) > MAX_CHECKPOINT_BYTES:
        raise ValueError(f"checkpoint of {len(data)} bytes exceeds the limit of {MAX_CHECKPOINT_BYTES} bytes "
                         f"(save less state, or a path to it)")
    return data


def save_checkpoint(state: Any) -> bool:
    """Save the running program's state (see ``ramps.checkpoint``). Returns
    whether it was sent: outside a worker, and within
    CHECKPOINT_MIN_INTERVAL of the last one, it is not (checked all the same)."""
    global _checkpoint_sent
    data = encode_checkpoint(state)
    out = _progress_out
    if out is None:
        return False
    now = time.monotonic()
    with _progress_lock:
        if now - _checkpoint_sent < CHECKPOINT_MIN_INTERVAL:
            return False
        _checkpoint_sent = now
        out.write(frame(_enc.encode({"checkpoint": data, "fraction": _progress_last})))
        out.flush()
    return True


def resume_state() -> Any:
    """The state the running program saved in an earlier attempt (moved or
    restarted after a failure), decoded; None on a fresh start."""
    data = _resume
    return None if data is None else _dec.decode(data)


def _cpu_seconds() -> float:
    """CPU seconds this worker and its waited-for children have used."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def run(inp: BinaryIO, out: BinaryIO) -> None:
    # progress state lives in the importable module that ``ramps.progress``
    # reaches, also when this file runs as ``__main__`` (python -m)
    from ramps.runtime import worker as this
    from ramps.runtime.command import CommandFailed
    from ramps.runtime.registry import MAX_RESULT_BYTES, decode_args, resolve

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
        with this._progress_lock:
            this._progress_out, this._progress_sent = out, 0.0
            this._checkpoint_sent, this._progress_last = -float("inf"), None
            this._resume = job[2] if len(job) > 2 else None
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
                if len(data) > MAX_RESULT_BYTES:
                    reply = [False, b"", f"program {program!r} returned {len(data)} bytes; results are limited to "
                                         f"{MAX_RESULT_BYTES} bytes (send a path or split the work)"]
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
        with this._progress_lock:
            this._progress_out = this._resume = None
            out.write(frame(_enc.encode(reply)))
            out.flush()


def main() -> None:
    if sys.argv[1:2] == ["--fork-server"]:  # the executor's fork server (ramps.runtime.forkserver)
        from ramps.runtime.forkserver import main as serve

        serve(int(sys.argv[2]), int(sys.argv[3]))
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
