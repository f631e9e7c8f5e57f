"""A burst placed as a whole (``ramps.core.burst``): programs an origin gets at
one instant wait for the end of the driver's batch, then go longest first
where the burst ends soonest; equal ones and other policies as before; a
cancelled one is not placed; nothing is lost or run twice when hosts fail."""

from __future__ import annotations

import msgspec
import pytest

from ramps.core.accelerators import Accelerator
from ramps.core.burst import PLAN_MAX, plan, pool_end
from ramps.core.events import Cancel, Deliver, StartProgram, Submit
from ramps.core.policy import Pool
from ramps.experiments import accelerators as family
from ramps.sim.engine import Simulator
from ramps.sim.scenario import ProgramSpec, RobotSpec, Scenario
from ramps.testing import FakeTeam


class _OneByOne(Simulator):
    """The simulator with every origin placing each program as it comes."""

    def _boot(self, r, now: float) -> None:
        super()._boot(r, now)
        r.node.origin.bursts = False


def _burst(team: FakeTeam, subs: list[Submit], robot: str = "o") -> None:
    """``subs`` reach ``robot`` in one batch of its driver's, which then ends."""
    node = team.nodes[robot]
    node.origin.bursts = True
    for sub in subs:
        team.handle(robot, sub)
    team.apply(robot, node.flush(team.now))
    team.deliver()


def _hosts(team: FakeTeam) -> dict[str, str]:
    return {a.program_id: robot for _, robot, a in team.log if isinstance(a, StartProgram)}


def two_robots() -> Scenario:
    # two one-core robots; origin o submits 1, 1 and then 2 units at once. One
    # by one, each where it ends first: o, a, then o again beside the first
    # (ends at 3). Longest first: the 2 alone on o, the two 1s sharing a (2 + T_comm)
    return Scenario(name="lpt", seed=1, robots=[RobotSpec(name="o", cores=1), RobotSpec(name="a", cores=1)],
                    programs=[ProgramSpec(origin="o", count=2, work=1.0), ProgramSpec(origin="o", work=2.0)])


def test_a_burst_placed_longest_first_ends_sooner_than_one_placed_in_order() -> None:
    sc = two_robots()
    one_by_one = _OneByOne(sc, seed=1).run()
    whole = Simulator(sc, seed=1).run()
    assert one_by_one.makespan == pytest.approx(3.0, abs=0.05)
    assert whole.makespan == pytest.approx(2.0, abs=0.05)
    assert {p.program_id: p.host for p in whole.programs} == {"o#1": "a", "o#2": "a", "o#3": "o"}
    assert whole.completed == 3 and whole.lost == whole.duplicated == 0


def test_the_same_burst_in_a_fake_team_is_planned_at_the_end_of_the_batch() -> None:
    team = FakeTeam({"o": (1, 1.0), "a": (1, 1.0)})
    team.publish()
    node = team.nodes["o"]
    node.origin.bursts = True
    for pid, work in (("p1", 1.0), ("p2", 1.0), ("p3", 2.0)):
        out = team.handle("o", Submit(program_id=pid, program="plan", work=work))
        # held: nothing placed yet (the first says at once that an application submits here)
        assert [type(a).__name__ for a in out] == (["PublishReport"] if pid == "p1" else [])
    assert node.next_deadline() == team.now  # due at once: a driver that only ticks places them too
    team.apply("o", node.tick(team.now))
    team.deliver()
    assert _hosts(team) == {"p3": "o", "p1": "a", "p2": "a"}
    assert node.next_deadline() != team.now and not node.origin.held


def test_without_bursts_each_program_is_placed_as_it_comes() -> None:
    team = FakeTeam({"o": (1, 1.0), "a": (1, 1.0)})
    team.publish()
    for pid, work in (("p1", 1.0), ("p2", 1.0), ("p3", 2.0)):
        team.handle("o", Submit(program_id=pid, program="plan", work=work))
    team.deliver()
    assert _hosts(team) == {"p1": "o", "p2": "a", "p3": "o"}


def test_equal_programs_and_policies_that_do_not_plan_are_placed_as_one_by_one() -> None:
    def hosts(policy: str, bursts: bool, works: list[float]) -> dict[str, str]:
        team = FakeTeam({"o": (2, 1.0), "a": (4, 2.0), "b": (1, 0.5)}, policy=policy)
        team.publish()
        subs = [Submit(program_id=f"p{i}", program="plan", work=w) for i, w in enumerate(works)]
        if bursts:
            _burst(team, subs)
        else:
            for sub in subs:
                team.handle("o", sub)
            team.deliver()
        return _hosts(team)

    equal = [5.0] * 9
    assert hosts("ramps", True, equal) == hosts("ramps", False, equal)
    mixed = [1.0, 2.0, 8.0, 1.0, 4.0]
    for policy in ("paper", "round_robin", "local_only"):
        assert hosts(policy, True, mixed) == hosts(policy, False, mixed)


def test_a_program_cancelled_before_its_burst_is_placed_is_never_offered() -> None:
    team = FakeTeam({"o": (1, 1.0), "a": (1, 1.0)})
    team.publish()
    node = team.nodes["o"]
    node.origin.bursts = True
    team.handle("o", Submit(program_id="p1", program="plan", work=1.0))
    team.handle("o", Submit(program_id="p2", program="plan", work=2.0))
    team.handle("o", Cancel(program_id="p1"))
    team.apply("o", node.flush(team.now))
    team.deliver()
    assert set(_hosts(team)) == {"p2"}
    [gone] = team.delivered("p1")
    assert gone.error_kind == "cancelled" and len(team.actions(Deliver)) == 1


def test_programs_with_deadlines_go_first_earliest_deadline_first() -> None:
    team = FakeTeam({"o": (1, 1.0), "a": (1, 1.0)})
    team.publish()
    _burst(team, [Submit(program_id="late", program="plan", work=1.0, deadline=50.0),
                  Submit(program_id="free", program="plan", work=3.0),
                  Submit(program_id="soon", program="plan", work=1.0, deadline=5.0)])
    placed = [n.program_id for n in team.notes("placed")]
    assert placed[:2] == ["soon", "late"] and placed[2] == "free"


def test_the_plan_keeps_the_slot_for_the_long_program_and_spreads_the_short_ones() -> None:
    # one slot of speed 10 and one core of speed 1; a long program (50 units
    # there, 10 on a core: 5 s or 10 s) and four short ones (10 units there,
    # 2 on a core: 1 s or 2 s). The long one and k short ones on the slot end
    # at 5 + k, the other 4 - k on the core at 2 (4 - k): k = 1 ends at 6 s,
    # the best there is (all on the slot: 9 s)
    slot = Pool(robot="g", kind="cuda", cores=1, speed=10.0)
    core = Pool(robot="o", kind="", cores=1, speed=1.0)

    def options(cpu: float, accel: float) -> dict:
        return {("g", "cuda"): msgspec.structs.replace(slot, work=accel),
                ("o", ""): msgspec.structs.replace(core, work=cpu)}

    where, ends = plan([options(10.0, 50.0)] + [options(2.0, 10.0)] * 4)
    assert max(ends.values()) == pytest.approx(6.0)
    assert where[0] == ("g", "cuda") and where.count(("o", "")) == 3


def test_a_pool_ends_when_its_largest_program_does() -> None:
    p = Pool(robot="o", kind="", cores=2, speed=1.0, known=(4.0,), unknown=1)
    # on two cores: 4 left, one of unknown work (as the largest placed, 6), and 2 and 6 placed: the
    # 2 ends at 4 s (half a core each), the 4 at 7 s (two thirds), the two 6s at 9 s; its result 0.1 s later
    assert pool_end(p, [2.0, 6.0], [0.0, 0.1]) == pytest.approx(9.1)
    assert pool_end(p, [], []) == 0.0


def test_a_large_burst_is_placed_longest_first_one_by_one() -> None:
    team = FakeTeam({"o": (2, 1.0), "a": (2, 1.0)})
    team.publish()
    subs = [Submit(program_id=f"p{i}", program="plan", work=1.0 + i % 5) for i in range(PLAN_MAX + 1)]
    _burst(team, subs)
    placed = [n.program_id for n in team.notes("placed")]
    works = [next(s.work for s in subs if s.program_id == pid) for pid in placed]
    assert works == sorted(works, reverse=True) and len(placed) == len(subs)


@pytest.mark.parametrize("index", [3, 4, 8, 9, 13, 14, 18, 19])  # crash, cut
def test_bursts_lose_nothing_and_run_nothing_twice_when_a_host_fails(index: int) -> None:
    sc = family.generate(index, 0)
    assert sc.faults
    res = Simulator(sc, seed=sc.seed).run()
    assert res.completed == sum(p.count for p in sc.programs)
    assert res.lost == res.duplicated == 0 and all(p.deliveries == 1 for p in res.programs)


def test_a_burst_on_an_accelerator_team_uses_the_slot_for_what_gains_most_from_it() -> None:
    cuda = [Accelerator(kind="cuda", count=1, speed=10.0)]
    team = FakeTeam({"o": (1, 1.0), "g": (1, 1.0)}, accelerators={"g": cuda})
    team.publish()
    long = Submit(program_id="long", program="big", work=10.0, accelerator="cuda", accelerator_work=50.0)
    short = [Submit(program_id=f"s{i}", program="small", work=2.0, accelerator="cuda", accelerator_work=10.0)
             for i in range(4)]
    _burst(team, short + [long])
    # as in the plan above (T_comm on g aside): the long one and one short one on the slot, three short
    # ones on o's core, 6 s; one by one, in this order, four on the slot and one on o: 8 s
    starts = {a.program_id: (robot, a.accelerator) for _, robot, a in team.log if isinstance(a, StartProgram)}
    assert starts["long"] == ("g", "cuda")
    assert sorted(starts.values()).count(("g", "cuda")) == 2 and sorted(starts.values()).count(("o", "")) == 3


def test_a_real_node_driver_places_a_round_of_submissions_together_and_delivers_each_once() -> None:
    from ramps.core.messages import ProgramOutcome, SubmitProgram, decode, encode
    from ramps.runtime import keys
    from ramps.testing.memory import MemoryTeam

    team = MemoryTeam({"r1": (1, 1.0), "r2": (4, 4.0), "r3": (4, 4.0)})
    try:
        team.run(3.0)  # everyone has heard everyone's reports
        outcomes: dict[int, list[ProgramOutcome]] = {}
        app = team.bus.transport("app")

        def heard(data: bytes) -> None:
            msg = decode(data).msg
            if isinstance(msg, ProgramOutcome):
                outcomes.setdefault(msg.request_id, []).append(msg)

        app.subscribe(keys.client(team.team, "app"), heard)
        works = [2.0, 2.0, 40.0, 2.0, 40.0, 2.0]
        for rid, work in enumerate(works, 1):  # all queued before the driver's next round
            app.put(keys.inbox(team.team, "r1"), encode("app", SubmitProgram(
                client="app", request_id=rid, program="echo", args=msgspec.msgpack.encode({"x": rid}), work=work)),
                block=True)
        team.run(60.0, until=lambda: len(outcomes) == len(works))
        team.run(5.0)
        assert sorted(outcomes) == list(range(1, len(works) + 1))
        assert all(len(v) == 1 and v[0].ok and v[0].attempts == 1 for v in outcomes.values())
        assert sum(len(p.ran) for p in team.pools.values()) == len(works)  # nothing ran twice
        origin = team.nodes["r1"].node.origin
        assert not origin.held and origin.placements == len(works)
        assert {outcomes[3][0].host, outcomes[5][0].host} <= {"r2", "r3"}  # the long ones on the fast robots
    finally:
        team.close()
