"""What an origin learns of its programs' work from completed runs
(``Origin._learn``): only runs long enough to measure, a resumed attempt as
the part it did, and a call far from its declaration flagged."""

from __future__ import annotations

import pytest

from ramps.core.events import Note, Received, Submit
from ramps.core.messages import ProgramResult
from ramps.core.learning import LEARN_MIN_PART, MISDECLARED
from ramps.core.speed import MIN_RUN_WORK
from ramps.sim.engine import simulate
from ramps.sim.scenario import ProgramSpec, RobotSpec, Scenario
from ramps.testing import FakeTeam


def _finish(team: FakeTeam, pid: str, declared: float, work_done: float, *, resumed_from: float | None = None,
            attempt_offset: int = 0) -> list:
    team.handle("o", Submit(program_id=pid, program="plan", work=declared))
    ap = team.nodes["o"].origin.programs[pid]
    ap.live[ap.attempt] = "o"
    ap.resumed_from = resumed_from
    return team.handle("o", Received(sender="o", msg=ProgramResult(
        program_id=pid, attempt=ap.attempt + attempt_offset, host="o", ok=True, value=b"", work_done=work_done)))


def _notes(actions: list) -> list[Note]:
    return [a for a in actions if isinstance(a, Note) and a.what == "misdeclared"]


def test_runs_too_short_to_measure_teach_nothing_but_are_flagged():
    team = FakeTeam({"o": (4, 1.0)})
    origin = team.nodes["o"].origin
    # warm-up calls that return at once while declaring 1.5 units
    for i in range(20):
        acts = _finish(team, f"w{i}", 1.5, 0.002)
        [note] = _notes(acts)
        assert "declared 1.5 work units, took 0.002" in note.detail
    assert origin.work_estimate(Submit(program_id="q", program="plan", work=1.5)) == 1.5
    assert "plan" not in origin.learned_work()
    # a measurable run that took its declaration is learned and not flagged
    assert _notes(_finish(team, "r1", 1.5, 1.6)) == []
    assert origin.work_estimate(Submit(program_id="q", program="plan", work=1.5)) == pytest.approx(1.6)
    # a short call declared short is neither learned nor flagged
    assert _notes(_finish(team, "s1", MIN_RUN_WORK / 4, MIN_RUN_WORK / 2)) == []
    # one that took MISDECLARED+ times its declaration is flagged and learned
    [note] = _notes(_finish(team, "b1", 1.0, 1.01 * MISDECLARED))
    assert "plan declared 1 work units" in note.detail


def test_a_resumed_attempt_counts_as_the_part_it_did():
    team = FakeTeam({"o": (4, 1.0)})
    origin = team.nodes["o"].origin
    # 60-unit programs: one ran whole, one resumed at 0.2 of its work did the other 48
    _finish(team, "a", 60.0, 60.0)
    _finish(team, "b", 60.0, 48.0, resumed_from=0.2)
    assert list(origin._learned["plan"]) == pytest.approx([1.0, 1.0])
    # one resumed near its end says nothing of the whole
    _finish(team, "c", 60.0, 3.0, resumed_from=1.0 - LEARN_MIN_PART / 2)
    assert len(origin._learned["plan"]) == 2
    # a result of an attempt that is no longer the program's (a move's old copy): its start is unknown
    _finish(team, "d", 60.0, 10.0, attempt_offset=-1)
    assert len(origin._learned["plan"]) == 2


def test_warm_up_calls_leave_the_real_ones_placed_as_declared():
    # 5 robots; the application first makes 20 calls that return at once (0.02 units
    # declared 40), then 30 real ones of 40 units: placed as declared, the same as
    # without the warm-up (before: learned as free, most stayed on the origin)
    robots = [RobotSpec(name=f"r{i}") for i in range(1, 6)]
    real = ProgramSpec(origin="r1", count=30, work=40.0, at=30.0, spacing=0.05)
    warm = ProgramSpec(origin="r1", count=20, work=0.02, work_estimate=40.0, spacing=0.5)
    cold = simulate(Scenario(robots=robots, programs=[real]), seed=1)
    warmed = simulate(Scenario(robots=robots, programs=[warm, real]), seed=1, trace=True)
    assert (warmed.completed, warmed.lost, warmed.duplicated) == (50, 0, 0)
    def real_makespan(res) -> float:
        return max(p.delivered_at or 0.0 for p in res.programs) - real.at

    assert real_makespan(warmed) == pytest.approx(real_makespan(cold), rel=0.05)
    flagged = [e for e in warmed.trace if e.what == "misdeclared"]
    assert len(flagged) == 20


def test_a_misdeclared_call_is_counted_in_the_metrics():
    from prometheus_client import generate_latest

    from ramps.runtime.metrics import NodeMetrics

    team = FakeTeam({"o": (4, 1.0)})
    metrics = NodeMetrics("o", "t")
    for pid, took in (("a", 0.002), ("b", 1.5), ("c", 0.001)):
        for action in _finish(team, pid, 1.5, took):
            metrics.on_action(action, team.nodes["o"], now=0.0)
    text = generate_latest(metrics.registry).decode()
    assert 'ramps_calls_misdeclared_total{program="plan",robot="o"} 2.0' in text


# ------------------------------------------------------------ a cost that depends on the arguments
def test_a_work_function_declares_each_call_from_its_arguments():
    from ramps.errors import BadArguments, ConfigError
    from ramps.runtime.registry import ProgramSpec as Spec
    from ramps.runtime.registry import program

    def plan(picks: int = 8, seed: int = 0) -> int:
        return picks

    spec = Spec("plan", "x:plan", work=lambda picks, **_: 0.2 * picks, _fn=plan)
    assert spec.declared_work({"picks": 20}) == pytest.approx(4.0)
    assert spec.declared_work({}) == pytest.approx(1.6)  # the program's default picks=8
    assert Spec("p", "x:p", work=2.5, _fn=plan).declared_work({"picks": 3}) == 2.5
    with pytest.raises(BadArguments, match="work function of program 'plan' failed"):
        Spec("plan", "x:plan", work=lambda picks, **_: 1 / (picks - 1), _fn=plan).declared_work({"picks": 1})
    with pytest.raises(BadArguments, match="returned -1"):
        Spec("plan", "x:plan", work=lambda **_: -1, _fn=plan).declared_work({})
    with pytest.raises(ConfigError, match="work is work units"):
        program("bad", work="lots")  # type: ignore[arg-type]


def test_a_client_and_a_node_declare_each_call_by_the_work_function(caplog):
    import msgspec

    import workprogs  # noqa: F401 (registers the program in this process: the client checks with it)
    from ramps.core.messages import SubmitProgram, encode
    from ramps.runtime import keys
    from ramps.testing.memory import MemoryTeam

    team = MemoryTeam({"r1": (2, 1.0)}, programs=["workprogs:sized"])
    app = team.connect("r1")
    try:
        futs = [app.submit("sized", picks=20), app.submit("sized")]
        team.run(2.0, until=lambda: all(f.done() for f in futs))
        assert [f.result(0) for f in futs] == [20, 4]
        # in-process, both returned at once: far below what they declare, said once for the program
        warned = [r.getMessage() for r in caplog.records if "declared" in r.getMessage()]
        assert len(warned) == 1 and warned[0].startswith("node r1: sized declared"), warned
        works = sorted(ap.submit.work for ap in team.nodes["r1"].node.origin.programs.values())
        assert works == pytest.approx([2.0, 10.0])  # 0.5 x 4 picks (the default) and 0.5 x 20
        # a client that does not have the program sends no work: the node declares it
        raw = team.bus.transport("other")
        raw.put(keys.inbox(team.team, "r1"), encode("other", SubmitProgram(
            client="other", request_id=1, program="sized", args=msgspec.msgpack.encode({"picks": 6}))), block=True)
        team.run(2.0, until=lambda: len(team.nodes["r1"].node.origin.programs) == 3)
        works = sorted(ap.submit.work for ap in team.nodes["r1"].node.origin.programs.values())
        assert works == pytest.approx([2.0, 3.0, 10.0])
    finally:
        app.close()
        team.close()


def test_route_plan_declares_its_work_by_picks_within_its_time_limit():
    from ramps.runtime.registry import BUILTINS, ROUTE_WORK, route_plan_work

    spec = BUILTINS["route_plan"]
    works = [spec.declared_work({"picks": p}) for p in range(4, 18)]
    assert works == sorted(works) and len(set(works)) == len(works)  # more picks, more work
    assert all(route_plan_work(picks=p) == pytest.approx(w) for p, w in ROUTE_WORK if w < 30)
    assert spec.declared_work({}) == pytest.approx(0.024)  # the program's default picks=8
    assert route_plan_work(picks=30) == 30.0  # capped by what 60 s of one worker computes
    assert route_plan_work(picks=30, time_limit=4.0, workers=2) == pytest.approx(4.0)
