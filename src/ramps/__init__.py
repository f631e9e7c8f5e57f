"""ramps: Reliable Autonomous Mobile Programs for robot teams.

Decentralised, fault-tolerant sharing of computational work across a team of
robots, after Valkov, Trinder & Chechina (Autonomous Robots, 2021).

Layout:
    ramps.core         sans-I/O protocol and decision logic (no clock, no network)
    ramps.sim          discrete-event simulator that drives ramps.core unchanged
    ramps.experiments  the paper's experiments, metrics and benchmarks
    ramps.cli          the ``ramps`` command
"""

__version__ = "0.2.0"


def connect(*args, **kwargs):
    """Join a team as an application; see ``ramps.runtime.client.connect``."""
    from ramps.runtime.client import connect as _connect

    return _connect(*args, **kwargs)


def program(*args, **kwargs):
    """Register a function as a ramps program; see ``ramps.runtime.registry.program``."""
    from ramps.runtime.registry import program as _program

    return _program(*args, **kwargs)


def progress(fraction: float, detail: str = "") -> bool:
    """From inside a running program: report how far it is (0..1).

    The fraction reaches the caller's future (``fut.progress``), ``ramps
    status`` and ROS action feedback. Outside a ramps worker it does nothing;
    see ``ramps.runtime.worker.report_progress``."""
    from ramps.runtime.worker import report_progress

    return report_progress(fraction, detail)


def checkpoint(state) -> bool:
    """From inside a running program: save its state, so that if it is moved
    to another robot or restarted after a failure it resumes from here
    (``ramps.resume()``) instead of starting over.

    ``state`` is bytes or anything msgspec can encode (dicts, lists, numbers,
    strings, Structs), at most 256 KiB encoded (``ValueError`` beyond, and
    ``TypeError`` for what cannot be encoded, also outside a worker). Report
    ``ramps.progress`` before it, so the origin knows how much work is left.
    Returns whether it was sent: at most five a second are, and outside a
    ramps worker none is. See ``ramps.runtime.worker.save_checkpoint``."""
    from ramps.runtime.worker import save_checkpoint

    return save_checkpoint(state)


def resume():
    """From inside a running program: the state it saved with
    ``ramps.checkpoint`` in an earlier attempt (decoded: bytes come back as
    bytes, other values as their plain msgpack form, e.g. a dict), or None on
    a fresh start (and outside a ramps worker)."""
    from ramps.runtime.worker import resume_state

    return resume_state()
