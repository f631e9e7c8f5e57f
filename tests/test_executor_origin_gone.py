"""The program executor and origins that are gone for good (issue 14).

A host used to keep running the programs of an origin that had crashed or
left, and to resend their results for ``result_retention`` (600 s). Now an
origin whose liveliness is lost and does not come back within
``origin_gone_after`` has its programs stopped and its results dropped; one
that comes back in time loses nothing.
"""

from __future__ import annotations

from ramps.core.config import RampsConfig
from ramps.core.events import Note, ProgramFinished, Send, StartProgram, StopProgram
from ramps.core.executor import ORIGIN_GONE_AFTER, Executor
from ramps.core.messages import Heartbeat, OffloadRequest, ProgramResult

CFG = RampsConfig()


def offer(ex: Executor, origin: str, pid: str, now: float) -> list:
    out: list = []
    ex.on_offload(OffloadRequest(program_id=pid, attempt=1, origin=origin, host="h", program="p", args=b"",
                                 work=1.0), now, out)
    assert any(isinstance(a, StartProgram) for a in out), out
    return out


def run_until(ex: Executor, start: float, end: float, step: float = 0.25) -> list:
    out: list = []
    t = start
    while t <= end:
        d = ex.next_deadline()
        if d is not None and d <= t:
            ex.tick(t, out)
        t += step
    return out


def test_programs_and_results_of_a_gone_origin_are_dropped():
    ex = Executor("h", config=CFG)
    offer(ex, "o1", "a", 0.0)
    offer(ex, "o1", "b", 0.0)
    offer(ex, "o2", "c", 0.0)
    out: list = []
    ex.on_finished(ProgramFinished(program_id="b", attempt=1, ok=True, value=b"1"), 1.0, out)
    assert ex.unacked_results() == 1
    ex.on_origin_lost("o1", 2.0)
    out = run_until(ex, 2.0, 2.0 + ORIGIN_GONE_AFTER + 1.0)
    stops = [a for a in out if isinstance(a, StopProgram)]
    assert [(a.program_id, a.attempt) for a in stops] == [("a", 1)]  # o2's program runs on
    assert set(ex.running) == {("c", 1)}
    assert ex.unacked_results() == 0  # b's result is no longer resent
    assert ex.orphans_stopped == 1
    assert {a.program_id for a in out if isinstance(a, Note) and a.what == "origin_gone"} == {"a", "b"}
    # and nothing is sent to o1 any more; o2 still gets its heartbeats
    later = run_until(ex, 2.0 + ORIGIN_GONE_AFTER + 1.0, 2.0 + ORIGIN_GONE_AFTER + 5.0)
    assert not [a for a in later if isinstance(a, Send) and a.to == "o1"]
    assert [a for a in later if isinstance(a, Send) and a.to == "o2" and isinstance(a.msg, Heartbeat)]


def test_an_origin_back_in_time_loses_nothing():
    ex = Executor("h", config=CFG)
    offer(ex, "o1", "a", 0.0)
    out: list = []
    ex.on_finished(ProgramFinished(program_id="a", attempt=1, ok=True, value=b"1"), 0.5, out)
    offer(ex, "o1", "b", 0.5)
    ex.on_origin_lost("o1", 1.0)
    run_until(ex, 1.0, 1.0 + ORIGIN_GONE_AFTER / 2)
    ex.on_origin_back("o1")
    out = run_until(ex, 1.0 + ORIGIN_GONE_AFTER / 2, 1.0 + 2 * ORIGIN_GONE_AFTER)
    assert not [a for a in out if isinstance(a, StopProgram)]
    assert set(ex.running) == {("b", 1)}
    assert [a for a in out if isinstance(a, Send) and isinstance(a.msg, ProgramResult)]  # still resent


def test_losing_an_origin_with_nothing_here_changes_nothing():
    ex = Executor("h", config=CFG)
    ex.on_origin_lost("o1", 0.0)
    assert ex.next_deadline() is None


def test_the_drop_happens_at_the_very_time_the_executor_wakes_for_it():
    """A simulator wakes the executor exactly at its deadline: ``since +
    origin_hold`` must drop the programs then, not find ``now - since`` a hair
    short of the hold and ask to be woken at the same instant for ever."""
    ex = Executor("h", config=CFG)
    since = 995.801795  # (since + hold) - since < hold in floating point
    assert (since + ORIGIN_GONE_AFTER) - since < ORIGIN_GONE_AFTER
    offer(ex, "o1", "a", since)
    ex.on_origin_lost("o1", since)
    out: list = []
    woken = []
    for _ in range(1000):  # each wake at the deadline the executor asked for, as the simulator does
        now = ex.next_deadline()
        if now is None or now > since + ORIGIN_GONE_AFTER:
            break
        woken.append(now)
        ex.tick(now, out)
    else:
        raise AssertionError(f"woken 1000 times, the last at {woken[-3:]}")
    assert woken[-1] == since + ORIGIN_GONE_AFTER
    assert [a.program_id for a in out if isinstance(a, StopProgram)] == ["a"]
