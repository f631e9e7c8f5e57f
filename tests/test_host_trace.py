"""A host's ``--trace`` says what it ran for other origins (started,
checkpointed, finished, stopped), and ``ramps report``'s timeline reads a
host's trace alone: real nodes over the in-memory team
(``ramps.testing.memory``), in milliseconds."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from ramps.observe.timeline import build_timeline, load_run
from ramps.testing.memory import MemoryTeam


@pytest.fixture
def traced(tmp_path):
    path = tmp_path / "team.jsonl"
    t = MemoryTeam({"r1": (1, 1.0), "r2": (4, 4.0)}, settings={"trace": str(path)}, programs=["e2eprogs:fail"])
    t.run(3.0)
    client = t.connect("r1")
    yield t, client, path
    client.close()
    t.close()


def _lines(path: Path, robot: str) -> list[dict]:
    """One robot's trace lines (every node of the memory team appends to one file)."""
    return [rec for rec in map(json.loads, path.read_text().splitlines()) if rec["robot"] == robot]


def _what(lines: list[dict]) -> list[tuple[str, str, int, str]]:
    return [(r["what"], r["other"], r["attempt"], r["detail"]) for r in lines if r["what"] != "tx"]


def test_a_host_traces_the_programs_it_runs_for_other_origins(traced):
    t, client, path = traced
    ok = client.options(work=20.0).submit("echo", x=1)
    bad = client.options(work=20.0).submit("fail")
    t.run(2.0, complete=False, until=lambda: len(t.pools["r2"].jobs) == 2)
    (pid_ok, att), (pid_bad, _) = list(t.pools["r2"].jobs)
    t.nodes["r2"].inbound.checkpoint_saved((pid_ok, att), b"state", 0.4)  # as a worker reports it
    t.run(30.0, until=lambda: ok.done() and bad.done())
    assert ok.host == bad.host == "r2"
    host = {(r["what"], r["program_id"]): r for r in _lines(path, "r2")}
    assert _what([host["started", pid_ok], host["checkpointed", pid_ok], host["finished", pid_ok]]) == [
        ("started", "r1", 1, "echo"), ("checkpointed", "r1", 1, "0.40"), ("finished", "r1", 1, "")]
    assert host["finished", pid_bad]["detail"] == "ValueError: no route to the dock"
    t.run(5.0)  # results resent until acknowledged are traced once
    assert sum(r["what"] == "finished" for r in _lines(path, "r2")) == 2
    assert not {r["what"] for r in _lines(path, "r1")} & {"started", "finished", "stopped"}  # its own: origin notes


def test_withdrawn_and_handed_back_programs_are_traced_as_stopped(traced):
    t, client, path = traced
    gone = client.options(work=20.0).submit("echo", x=1)
    kept = client.options(work=20.0).submit("echo", x=2)
    t.run(2.0, complete=False, until=lambda: len(t.pools["r2"].jobs) == 2)
    gone.cancel()
    t.run(1.0, complete=False)
    t.stop("r2")  # leaves: hands its other program back to r1
    t.run(30.0, until=kept.done)
    assert kept.result(0) == {"x": 2} and kept.host == "r1"
    stopped = [(r["other"], r["detail"]) for r in _lines(path, "r2") if r["what"] == "stopped"]
    assert stopped == [("r1", ""), ("r1", "handed back")]


def test_a_hosts_trace_alone_shows_what_ran_there(traced, tmp_path):
    t, client, path = traced
    futs = [client.options(work=20.0).submit("echo", x=i) for i in range(3)]
    t.run(30.0, until=lambda: all(f.done() for f in futs))
    host_file = tmp_path / "r2.jsonl"
    host_file.write_text("".join(json.dumps(r) + "\n" for r in _lines(path, "r2")))
    tl = build_timeline(*load_run([host_file]))
    assert tl.robots == ["r1", "r2"]
    assert [(a.host, a.origin, a.outcome) for a in tl.attempts] == [("r2", "r1", "finished")] * 3
    assert all(a.accepted is not None and a.end is not None and a.end >= a.accepted for a in tl.attempts)
    # with the origin's trace beside it, the origin's view wins: delivered, ending at the delivery
    merged = build_timeline(*load_run([path]))
    assert [(a.host, a.outcome) for a in merged.attempts] == [("r2", "delivered")] * 3
    assert merged.distribution == {"r1": 0, "r2": 3}
