"""``python -m ramps.bench.dispatchorigin`` drives a real origin node and a
teammate through a client's submissions: every program runs once, on one
robot or the other, its client gets one outcome each, and the figure is one
per round (no duration asserted)."""

from __future__ import annotations

from collections import Counter

from ramps.bench import dispatchorigin


def test_the_origin_bench_runs_every_program_once_and_gives_one_figure_a_round(monkeypatch):
    ran: Counter = Counter()
    from ramps.testing import memory

    real_run = memory.MemoryPool.run

    def run(self, key, *a, **kw):
        ran[key] += 1
        return real_run(self, key, *a, **kw)

    monkeypatch.setattr(memory.MemoryPool, "run", run)
    got = dispatchorigin.origin_cpu(programs=12, batch=5, rounds=2)
    assert len(got) == 2 and all(x > 0 for x in got)
    assert len(ran) == 24 and set(ran.values()) == {1}
    assert {pid.split("#")[0] for pid, _ in ran} == {"o"}  # the origin's programs, wherever they ran
