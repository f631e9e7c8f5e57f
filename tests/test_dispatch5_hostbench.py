"""``python -m ramps.bench.dispatchhost`` drives a real host node through
offers, ends and acknowledgements: every program runs once and is
acknowledged, and the figure is one per round (no duration asserted)."""

from __future__ import annotations

from ramps.bench import dispatchhost


def test_the_host_bench_runs_every_program_and_gives_one_figure_a_round(monkeypatch):
    ran: list = []
    from ramps.testing import memory

    real_run = memory.MemoryPool.run

    def run(self, key, *a, **kw):
        ran.append(key)
        return real_run(self, key, *a, **kw)

    monkeypatch.setattr(memory.MemoryPool, "run", run)
    got = dispatchhost.host_cpu(programs=12, batch=5, rounds=2)
    assert len(got) == 2 and all(x > 0 for x in got)
    assert sorted(ran) == sorted((f"p{r}-{i}", 1) for r in range(2) for i in range(12))
