"""ramps: Reliable Autonomous Mobile Programs for robot teams.

Decentralised, fault-tolerant sharing of computational work across a team of
robots, after Valkov, Trinder & Chechina (Autonomous Robots, 2021).

Layout:
    ramps.core         sans-I/O protocol and decision logic (no clock, no network)
    ramps.sim          discrete-event simulator that drives ramps.core unchanged
    ramps.experiments  the paper's experiments, metrics and benchmarks
    ramps.cli          the ``ramps`` command
"""

__version__ = "0.1.0"


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
