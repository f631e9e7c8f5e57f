"""Programs that ramps distributes: plain functions, installed on every robot.

A program is an ordinary Python function registered by name; only its
arguments and its result travel between robots, as msgspec-serialisable data
(never pickles). The modules here are the workloads used by examples,
benchmarks and experiments:

    ramps.programs.route  warehouse order-picking route planning (OR-Tools CP-SAT),
                          the paper's workload ("explore routes starting from
                          different adjacent locations")
    ramps.programs.burn   a calibrated pure-Python CPU burn, plus ``noop`` and
                          ``echo`` for dispatch benchmarks

Rule: importing this package (or ``route``) must stay cheap, so nothing heavy
is re-exported here and OR-Tools is imported lazily, inside the solver call.
"""
