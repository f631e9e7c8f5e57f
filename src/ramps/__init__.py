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
