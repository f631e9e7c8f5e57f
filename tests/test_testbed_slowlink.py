"""The slow-link experiment's program (ramps.testbed.slowlink) and report (ramps.lab.slowlink);
the experiment itself needs root and a testbed: ``ramps testbed experiment slow-link``."""

from __future__ import annotations

from ramps.lab.slowlink import LinkSample, SlowLinkReport, SlowLinkRun, format_report
from ramps.runtime.registry import default_registry, encode_args
from ramps.testbed.slowlink import crunch


def test_crunch_is_a_registered_program_taking_a_megabyte_of_parameters():
    assert crunch(data=b"x" * 1000, units=0.001) == {"bytes": 1000}
    spec = default_registry.get("crunch")
    assert len(encode_args(spec, {"data": b"x" * 1_000_000, "units": 0.3})) > 1_000_000


def test_the_report_shows_both_runs_and_the_estimates():
    runs = [SlowLinkRun(shaped=False, distribution=[0, 1, 5], durations=[7.0] * 6,
                        links={"r2": [0.0011, 0.92e6], "r3": [0.0019, 1.02e6]}),
            SlowLinkRun(shaped=True, distribution=[0, 6, 0], durations=[7.5] * 6,
                        links={"r2": [0.0013, 2.16e6], "r3": [0.0016, None]},
                        convergence=[LinkSample(t=0.0, latency=None, bandwidth=None),
                                     LinkSample(t=9.0, latency=0.0016, bandwidth=0.806e6)])]
    text = format_report(SlowLinkReport(rate=1e6, payload=1_000_000, units=0.3, slow="r3", runs=runs))
    assert "full speed: r1-r2-r3 0-1-5" in text and "r3 slowed: r1-r2-r3 0-6-0" in text
    assert "r3: 1.6 ms, not measured" in text and "9 s 0.806 MB/s" in text
