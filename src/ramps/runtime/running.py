"""A running program's side of its worker: progress, checkpoints, resume.

How this works: ``ramps.progress``, ``ramps.checkpoint`` and ``ramps.resume``
(and an executable's ``RAMPS_PROGRESS`` and ``RAMPS_CHECKPOINT`` lines,
``ramps.runtime.command``) end here. The worker (``ramps.runtime.worker``)
calls ``begin`` before each program, with its result pipe and the state an
earlier attempt saved, and ``end`` with the program's reply: in between,
``report_progress`` and ``save_checkpoint`` write their frames to that pipe
(at most one every ``PROGRESS_MIN_INTERVAL`` and ``CHECKPOINT_MIN_INTERVAL``)
and ``resume_state`` decodes the saved state. Outside a worker (a program
called directly, in a test) they send nothing.

Rules: one lock orders every frame of a program, so its reply is always its
last; what a program sends is bounded here (``MAX_CHECKPOINT_BYTES`` for a
checkpoint, ``MAX_RESULT_BYTES`` for a result).
"""

from __future__ import annotations

import math
import threading
import time
from typing import Any, BinaryIO

import msgspec

from ramps.core.messages import MAX_CHECKPOINT_BYTES, MAX_MESSAGE_BYTES
from ramps.runtime.frames import frame

#: largest encoded result a program may return, bytes: like its arguments
#: (``ramps.runtime.registry.MAX_ARGS_BYTES``) it must fit in one wire message
MAX_RESULT_BYTES = MAX_MESSAGE_BYTES - 64 * 1024
#: at most one progress frame per this many seconds (the last one is never lost
#: for long: the host forwards the newest with its next heartbeat anyway)
PROGRESS_MIN_INTERVAL = 0.05
#: longest progress text sent
PROGRESS_TEXT = 200
#: at most one checkpoint per this many seconds (a program may call it in a loop)
CHECKPOINT_MIN_INTERVAL = 0.2

_enc = msgspec.msgpack.Encoder()
_dec = msgspec.msgpack.Decoder()
_lock = threading.Lock()
#: the running program's result pipe (None: no program runs in a worker here)
_out: BinaryIO | None = None
_progress_sent = 0.0
_checkpoint_sent = -float("inf")
#: the newest progress the running program reported (sent with its checkpoints)
_progress_last: float | None = None
#: the running program's resume state (msgpack), None on a fresh start
_resume: bytes | None = None
#: the accelerator the running program was given (``Grant.as_wire``), None on a CPU
_grant: dict[str, Any] | None = None


def begin(out: BinaryIO, resume: bytes | None, grant: dict[str, Any] | None = None) -> None:
    """A program starts: its frames go to ``out``; ``resume`` is the state an
    earlier attempt saved (msgpack), None on a fresh start; ``grant`` the
    accelerator its node gave it (``Grant.as_wire``), None on a CPU."""
    global _out, _progress_sent, _checkpoint_sent, _progress_last, _resume, _grant
    with _lock:
        _out, _progress_sent = out, 0.0
        _checkpoint_sent, _progress_last = -float("inf"), None
        _resume = resume
        _grant = grant


def end(out: BinaryIO, reply: bytes) -> None:
    """The program ended: ``reply`` is its last frame on ``out``; what it
    sends later (a thread it left running) goes nowhere."""
    global _out, _resume, _grant
    with _lock:
        _out = _resume = _grant = None
        out.write(frame(reply))
        out.flush()


def report_progress(fraction: float, detail: str = "") -> bool:
    """Tell the caller how far the running program is (0..1, clamped).

    Inside a worker the value travels to the program's origin and its
    caller; anywhere else (a program called directly, in a test) it does
    nothing. Returns whether it was sent. Cheap enough to call in a loop:
    calls closer together than PROGRESS_MIN_INTERVAL are dropped, except 1.0."""
    global _progress_sent, _progress_last
    out = _out
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
    with _lock:
        if now - _progress_sent < PROGRESS_MIN_INTERVAL and f < 1.0:
            return False
        _progress_sent = now
        _progress_last = f
        out.write(frame(_enc.encode({"progress": f, "detail": str(detail)[:PROGRESS_TEXT]})))
        out.flush()
    return True


def encode_checkpoint(state: Any) -> bytes:
    """A program's state as a checkpoint travels: msgpack, at most
    MAX_CHECKPOINT_BYTES (``bytes`` stay bytes, anything else msgspec can
    encode comes back as its plain msgpack form)."""
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
    out = _out
    if out is None:
        return False
    now = time.monotonic()
    with _lock:
        if now - _checkpoint_sent < CHECKPOINT_MIN_INTERVAL:
            return False
        _checkpoint_sent = now
        out.write(frame(_enc.encode({"checkpoint": data, "fraction": _progress_last})))
        out.flush()
    return True


def accelerator_grant() -> Any:
    """The accelerator the running program was given (a
    ``ramps.runtime.accelerators.Grant``), or None: it runs on a CPU, or
    outside a ramps worker."""
    data = _grant
    if data is None:
        return None
    from ramps.runtime.accelerators import Grant

    return Grant.from_wire(data)


def resume_state() -> Any:
    """The state the running program saved in an earlier attempt (moved or
    restarted after a failure), decoded; None on a fresh start."""
    data = _resume
    return None if data is None else _dec.decode(data)
