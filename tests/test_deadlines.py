"""Deadlines in the core: placement, ``on_miss``, host admission, misses.

Team of ``busy_origin_team``: the origin ``o`` is swamped, ``a`` (speed 2)
computes a 50-unit program in about 25 s, ``b`` (speed 1) in 50 s.
"""

from __future__ import annotations

import random

import pytest

from ramps.core.events import Deliver, Received, StartProgram, Submit
from ramps.core.messages import OffloadRejected, OffloadRequest
from ramps.core.policy import PlacementRequest, RampsPolicy

from corehelpers import CFG, NET, busy_origin_team, report, submit, view_of
from ramps.testing import FakeTeam


def test_a_loose_deadline_goes_to_the_slowest_host_in_time() -> None:
    # best fit: b (50 s) meets 100 s and 60 s (no margin kept) and leaves a
    # to tighter programs; b misses 40 s, so a (25 s) takes it, as with none
    plain, loose, snug, tighter = busy_origin_team(), busy_origin_team(), busy_origin_team(), busy_origin_team()
    submit(plain)
    submit(loose, deadline=100.0)
    submit(snug, deadline=60.0)
    submit(tighter, deadline=40.0)
    [p] = plain.sent(OffloadRequest)
    [q] = loose.sent(OffloadRequest)
    [s] = snug.sent(OffloadRequest)
    [r] = tighter.sent(OffloadRequest)
    assert (p.host, q.host, s.host, r.host) == ("a", "b", "b", "a")
    assert p.deadline_in is None
    assert q.deadline_in == pytest.approx(100.0)  # the host admits against it
    assert q.time_budget == pytest.approx(100.0, abs=0.1)  # what the deadline leaves
    assert not loose.notes("deadline_unmet") and not tighter.notes("deadline_unmet")


def test_unmeetable_deadline_runs_where_fastest_by_default() -> None:
    team = busy_origin_team()
    submit(team, deadline=10.0)
    [req] = team.sent(OffloadRequest)
    assert req.host == "a" and req.deadline_in is None  # run anyway: the host must not turn it away
    [note] = team.notes("deadline_unmet")
    assert "on_miss=run" in note.detail and "10.00 s left" in note.detail


def test_unmeetable_deadline_with_on_miss_local_runs_on_the_origin() -> None:
    team = busy_origin_team()
    submit(team, deadline=10.0, on_miss="local")
    assert [n.robot for n in team.notes("placed")] == ["o"]
    assert not team.sent(OffloadRequest)
    team.deliver()
    assert [s.program_id for s in team.actions(StartProgram, "o")] == ["p"]


def test_unmeetable_deadline_with_on_miss_fail_fails_before_anything_runs() -> None:
    team = busy_origin_team()
    submit(team, deadline=10.0, on_miss="fail")
    assert not team.sent(OffloadRequest)
    [d] = team.delivered("p")
    assert (d.ok, d.error_kind, d.missed_deadline, d.host) == (False, "deadline", True, "a")
    assert "cannot meet its deadline" in d.error and "25." in d.error and "on a" in d.error
    assert team.nodes["o"].origin.deadline_misses == 1
    assert [n.detail for n in team.notes("deadline_missed")] == ["unmeetable"]


def test_a_meetable_deadline_with_on_miss_fail_runs() -> None:
    team = busy_origin_team()
    submit(team, deadline=40.0, on_miss="fail")
    [req] = team.sent(OffloadRequest)
    assert req.host == "a" and req.deadline_in == pytest.approx(40.0)


@pytest.mark.parametrize("seed", range(8))
def test_of_hosts_tied_on_cost_only_those_in_time_are_chosen(seed: int) -> None:
    # a and b cost the same within the tie tolerance; only a ends by the deadline
    view = view_of("o", report("o", cores=1, runnable=10.0), report("a", speed=1.0), report("b", speed=0.998),
                   cores=1)
    policy = RampsPolicy()
    req = PlacementRequest(program_id="x", work=53.0, payload_size=1000, result_size=1000)
    t_a = 53.0 + 3 * NET.latency + 2000 / NET.bandwidth
    picks = {policy.choose(req, view, 1.0, random.Random(s), net=NET, config=CFG).host for s in range(20)}
    assert picks == {"a", "b"}  # without a deadline, chance decides between them
    timed = msgspec_replace(req, deadline=t_a + 0.01)
    p = policy.choose(timed, view, 1.0, random.Random(seed), net=NET, config=CFG)
    assert (p.host, p.late) == ("a", False)
    late = policy.choose(msgspec_replace(req, deadline=10.0), view, 1.0, random.Random(seed), net=NET, config=CFG)
    assert late.late and late.expected_time == pytest.approx(t_a, rel=0.01)


def msgspec_replace(req: PlacementRequest, **kw) -> PlacementRequest:
    import msgspec

    return msgspec.structs.replace(req, **kw)


def _offer(deadline_in: float | None, *, force: bool = False) -> OffloadRequest:
    return OffloadRequest(program_id="q", attempt=1, origin="o", host="b", program="route_plan", work=50.0,
                          deadline_in=deadline_in, force=force)


@pytest.mark.parametrize("deadline_in, force, admitted", [
    (None, False, True),     # no deadline: taken
    (60.0, False, True),     # 50 s here: in time
    (30.0, False, False),    # 50 s here: "late", turned away
    (30.0, True, True),      # forced after too many rejections: taken
])
def test_host_admits_against_the_deadline(deadline_in, force, admitted) -> None:
    team = busy_origin_team()
    team.handle("b", Received(sender="o", msg=_offer(deadline_in, force=force)))
    rejected = team.sent(OffloadRejected, by="b")
    assert bool(team.actions(StartProgram, "b")) is admitted
    if not admitted:
        [r] = rejected
        assert (r.reason, r.permanent) == ("late", False)
        assert r.report is not None  # fresh load, so the origin places again with it
        assert "50.00 s here" in r.detail


def test_a_late_rejection_leaves_the_host_out_and_places_again_at_once() -> None:
    team = busy_origin_team()
    team.nodes["a"].executor.background = 8.0  # a is busier than o's view says: 50/(2*4/9) = 56 s
    submit(team, deadline=40.0)
    team.deliver()
    [rej] = team.sent(OffloadRejected, by="a")
    assert rej.reason == "late"
    # a would only turn it away again; no other host makes 40 s either: it
    # runs anyway on b, where it ends soonest without a
    assert team.notes("deadline_unmet")
    assert [req.host for req in team.sent(OffloadRequest)] == ["a", "b"]
    assert team.actions(StartProgram, "b")
    assert not team.notes("backoff")


@pytest.mark.parametrize("finish_at, missed", [(20.0, False), (45.0, True)])
def test_a_result_after_the_deadline_is_a_miss(finish_at: float, missed: bool) -> None:
    team = busy_origin_team()
    submit(team, deadline=30.0)
    team.deliver()
    team.advance(finish_at)
    team.publish()
    team.finish("a", "p", 1, ok=True, value=b"v")
    [d] = team.delivered("p")
    assert d.ok and d.missed_deadline is missed
    assert team.nodes["o"].origin.deadline_misses == int(missed)
    notes = team.notes("deadline_missed")
    assert [n.detail for n in notes] == (["15.000 s late"] if missed else [])


def test_deliver_without_deadline_is_never_a_miss() -> None:
    team = busy_origin_team()
    submit(team)
    team.deliver()
    team.advance(500.0)
    team.finish("a", "p", 1, ok=True)
    [d] = team.actions(Deliver)
    assert not d.missed_deadline


def test_bad_on_miss_and_deadline_are_refused() -> None:
    team = busy_origin_team()
    with pytest.raises(ValueError, match="on_miss"):
        team.handle("o", Submit(program_id="p", program="x", work=1.0, on_miss="maybe"))
    with pytest.raises(ValueError, match="finite"):
        team.handle("o", Submit(program_id="q", program="x", work=1.0, deadline=float("nan")))


def test_host_keeps_the_deadlines_it_admitted() -> None:
    team = busy_origin_team()
    for i in range(4):  # b's 4 cores, 50 s each, due in 55 s
        offer = OffloadRequest(program_id=f"d{i}", attempt=1, origin="o", host="b", program="route_plan",
                               work=50.0, deadline_in=55.0)
        team.handle("b", Received(sender="o", msg=offer))
    assert len(team.actions(StartProgram, "b")) == 4
    # a fifth, with no deadline of its own, would slow all four to 62.5 s
    fifth = OffloadRequest(program_id="e", attempt=1, origin="o", host="b", program="route_plan", work=50.0,
                           expected_runnable=4.0, time_budget=1000.0)
    team.handle("b", Received(sender="o", msg=fifth))
    [r] = team.sent(OffloadRejected, by="b")
    assert (r.reason, r.detail) == ("late", "would make 4 programs here miss their deadline")
    # an origin that does not negotiate (no expected_runnable), or one forced, is not turned away
    for msg in (msgspec_replace_offer(fifth, program_id="f", expected_runnable=None, time_budget=None),
                msgspec_replace_offer(fifth, program_id="g", force=True)):
        team.handle("b", Received(sender="o", msg=msg))
    assert len(team.actions(StartProgram, "b")) == 6


def test_a_host_counts_a_deadline_missed_by_less_than_its_tolerance_as_missed() -> None:
    # b's 4 cores run 4 programs of 50 s due in 55 s; a fifth of 22 units
    # shares them for 27.5 s and they end at 55.5 s: 0.5 s late, within the
    # 2% admission tolerance, which is for the origin's estimate of the
    # program offered, not for whether a program here would miss its deadline
    team = busy_origin_team()
    for i in range(4):
        team.handle("b", Received(sender="o", msg=OffloadRequest(
            program_id=f"d{i}", attempt=1, origin="o", host="b", program="route_plan", work=50.0, deadline_in=55.0)))
    fifth = OffloadRequest(program_id="e", attempt=1, origin="o", host="b", program="route_plan", work=22.0,
                           expected_runnable=4.0, time_budget=1000.0)
    team.handle("b", Received(sender="o", msg=fifth))
    [r] = team.sent(OffloadRejected, by="b")
    assert (r.reason, r.detail) == ("late", "would make 4 programs here miss their deadline")
    small = msgspec_replace_offer(fifth, program_id="s", work=18.0)  # they end at 54.5 s: in time
    team.handle("b", Received(sender="o", msg=small))
    assert len(team.actions(StartProgram, "b")) == 5


def msgspec_replace_offer(req: OffloadRequest, **kw) -> OffloadRequest:
    import msgspec

    return msgspec.structs.replace(req, **kw)


@pytest.mark.parametrize("deadline, told", [(200.0, True), (65.0, False)])
def test_a_move_tells_the_new_host_the_seconds_left(deadline: float, told: bool) -> None:
    # p (60 s alone on a or b) runs on one of them, whose own software then
    # starts 8 busy processes (135 s there): it moves. In time on the new
    # host, the offer carries what is left of the deadline; not in time
    # (65 s: 56 s left at the move), it moves anyway without one
    team = FakeTeam({"o": (1, 1.0), "a": (4, 1.0), "b": (4, 1.0)})
    team.nodes["o"].executor.background = 10.0
    team.publish()
    submit(team, work=60.0, deadline=deadline)
    team.deliver()
    first = team.program("p").host
    other = "b" if first == "a" else "a"
    team.advance(1.0)
    team.nodes[first].executor.background = 8.0
    for t in range(1, 12):
        team.advance(float(t))
        team.publish()
    [move] = team.sent(OffloadRequest, to=other)
    [note] = team.notes("moving")
    moved_at = next(when for when, _, a in team.log if a is note)
    if told:
        assert move.deadline_in == pytest.approx(deadline - moved_at)
        assert team.program("p").moves == 1 and team.actions(StartProgram, other)  # the new host took it
    else:
        assert move.deadline_in is None


def test_a_host_protecting_the_deadlines_it_runs_is_left_out_and_the_origin_places_elsewhere() -> None:
    # a (4 cores, speed 2) runs z's four 50-unit programs due in 28 s (25 s
    # each); a fifth would slow them to 31.25 s. o's view, fresh from a's
    # report, still puts p (no deadline of its own) on a: 31 s there, 50 s
    # on b. a turns it away as "late", and o places it on b at once
    team = FakeTeam({"o": (1, 1.0), "a": (4, 2.0), "b": (4, 1.0), "z": (1, 1.0)})
    for swamped in ("o", "z"):
        team.nodes[swamped].executor.background = 10.0
    for i in range(4):
        team.handle("a", Received(sender="z", msg=OffloadRequest(
            program_id=f"d{i}", attempt=1, origin="z", host="a", program="route_plan", work=50.0, deadline_in=28.0)))
    team.deliver()
    team.publish()
    submit(team)
    team.deliver()
    [rej] = team.sent(OffloadRejected, by="a")
    assert (rej.reason, rej.detail) == ("late", "would make 4 programs here miss their deadline")
    assert [req.host for req in team.sent(OffloadRequest, by="o")] == ["a", "b"]
    assert [s.program_id for s in team.actions(StartProgram, "b")] == ["p"]
    assert sorted(pid for pid, _ in team.nodes["a"].executor.running) == ["d0", "d1", "d2", "d3"]
    assert not team.notes("backoff") and not team.notes("deadline_unmet")
