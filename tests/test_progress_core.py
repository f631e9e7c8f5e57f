"""Progress through the real core: host executor -> ProgramProgress -> origin -> Progress action.

Scenarios on ``ramps.testing.FakeTeam`` (no clock, no network): a program
running on another robot reports progress; the origin passes on the newest
value once per heartbeat period; a stale attempt's progress and progress
after the result are dropped; a program that runs locally reports too.
"""

from __future__ import annotations

from ramps.core.events import Progress, ProgressReported, Received, StartProgram, Submit
from ramps.core.messages import ProgramProgress
from ramps.testing import FakeTeam


def _team() -> FakeTeam:
    t = FakeTeam({"o": (1, 1.0), "h": (4, 1.0)})
    t.publish()
    return t


def _submit_remote(t: FakeTeam, pid: str = "p1") -> StartProgram:
    t.handle("o", Submit(program_id=pid, program="burn", work=50.0))
    t.deliver()
    starts = [a for a in t.actions(StartProgram, "h") if a.program_id == pid]
    assert starts, "the idle 4-core robot should host a 50-unit program"
    return starts[-1]


def test_progress_travels_at_once_then_at_most_with_each_heartbeat() -> None:
    t = _team()
    start = _submit_remote(t)
    for f in (0.1, 0.2, 0.42):  # the first travels at once; the rest of the period, only the newest
        t.handle("h", ProgressReported(program_id="p1", attempt=start.attempt, fraction=f, detail=f"step {f}"))
        t.deliver()
    assert [p.fraction for p in t.actions(Progress, "o")] == [0.1]
    t.advance(t.now + 0.6)
    got = t.actions(Progress, "o")
    assert [(p.program_id, p.host, p.attempt, p.fraction, p.detail) for p in got] == \
        [("p1", "h", start.attempt, 0.1, "step 0.1"), ("p1", "h", start.attempt, 0.42, "step 0.42")]
    assert len(t.sent(ProgramProgress, by="h", to="o")) == 2
    # no new progress: the next heartbeats carry none
    t.advance(t.now + 2.0)
    assert len(t.actions(Progress, "o")) == 2
    t.handle("h", ProgressReported(program_id="p1", attempt=start.attempt, fraction=0.9))  # quiet for long: at once
    t.deliver()
    assert [p.fraction for p in t.actions(Progress, "o")] == [0.1, 0.42, 0.9]


def test_out_of_range_progress_is_clamped_and_long_text_cut() -> None:
    t = _team()
    start = _submit_remote(t)
    t.handle("h", ProgressReported(program_id="p1", attempt=start.attempt, fraction=7.0, detail="x" * 5000))
    t.advance(t.now + 0.6)
    (p,) = t.actions(Progress, "o")
    assert p.fraction == 1.0 and len(p.detail) == 256
    t.handle("h", ProgressReported(program_id="p1", attempt=start.attempt, fraction=float("nan")))
    t.advance(t.now + 0.6)
    assert t.actions(Progress, "o")[-1].fraction == 0.0


def test_progress_after_the_result_or_from_a_stale_attempt_is_dropped() -> None:
    t = _team()
    start = _submit_remote(t)
    t.finish("h", "p1", start.attempt, ok=True, value=b"\x01")
    assert t.delivered("p1")
    # progress for an ended program: the executor forgot it
    t.handle("h", ProgressReported(program_id="p1", attempt=start.attempt, fraction=0.5))
    t.advance(t.now + 1.0)
    assert not t.sent(ProgramProgress, by="h")
    # a hostile or late ProgramProgress straight at the origin changes nothing
    t.handle("o", Received(
        sender="h", msg=ProgramProgress(program_id="p1", attempt=start.attempt, host="h", fraction=0.5)))
    t.handle("o", Received(
        sender="x", msg=ProgramProgress(program_id="nope", attempt=1, host="x", fraction=0.5)))
    assert not t.actions(Progress, "o")
    assert t.nodes["o"].origin.anomalies == 0  # advisory: not an anomaly


def test_a_program_run_locally_reports_progress_too() -> None:
    t = FakeTeam({"o": (2, 1.0)})
    t.publish()
    t.handle("o", Submit(program_id="p1", program="burn", work=1.0, local_only=True))
    (start,) = t.actions(StartProgram, "o")
    t.handle("o", ProgressReported(program_id="p1", attempt=start.attempt, fraction=0.5, detail="half"))
    t.advance(t.now + 0.6)
    (p,) = t.actions(Progress, "o")
    assert (p.host, p.fraction, p.detail) == ("o", 0.5, "half")
