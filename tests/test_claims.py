"""Bursts of several origins at one instant (``ramps.core.claims``): the
origins place in the order of their names, each counting the claims of
those before it, so two do not plan on the same slot; an origin alone
waits for nothing."""

from __future__ import annotations

import msgspec

from ramps.core.config import RampsConfig
from ramps.core.messages import BurstClaim, ClaimedPool, decode, encode
from ramps.sim.engine import Simulator
from ramps.sim.scenario import ProgramSpec, RobotSpec, Scenario

# three one-core robots of speed 1, g with one slot of speed 10. At one
# instant, origin a submits a long program (30 units on the slot, 3 s; 60 on
# a core) with large parameters (0.1 s on the link), origin b a short one (10
# units on the slot, 1 s; 1.5 on a core); each a small CPU one too. Each alone ends
# first on the slot. Blind to each other, b's offer reaches g first and is
# taken; a's comes 0.1 s later, one program more than it expected, within
# admission's slack and its budget: the two share the slot and a's ends at
# about 4 s. Seeing a's claim (a is first by name), b runs its short program
# on its own core: 3.1 s
LONG = ProgramSpec(origin="a", program="long", work=60.0, accelerator="cuda", accelerator_work=30.0,
                   payload=250_000, result=100)
SHORT = ProgramSpec(origin="b", program="short", work=1.5, accelerator="cuda", accelerator_work=10.0,
                    payload=100, result=100)
CPU = ProgramSpec(origin="b", program="cpu", work=0.5, payload=100, result=100)
A_CPU = msgspec.structs.replace(CPU, origin="a")


def one_slot(programs: tuple[ProgramSpec, ...] = (LONG, A_CPU, SHORT, CPU), claims: bool = True) -> Scenario:
    robots = [RobotSpec(name=n, cores=1) for n in ("a", "b")] + [RobotSpec(name="g", cores=1, accelerators=["cuda:1:10"])]
    return Scenario(name="one-slot", seed=3, robots=robots, config=RampsConfig(burst_claims=claims),
                    programs=list(programs))


def res_net() -> float:
    return one_slot().network.latency


class _Recording(Simulator):
    """The simulator, keeping every claim sent: (from, to, planned)."""

    def _send(self, src, to, msg) -> None:
        if isinstance(msg, BurstClaim):
            self.claims.append((src.spec.name, to, msg.planned))
        super()._send(src, to, msg)


def _run(sc: Scenario):
    sim = _Recording(sc, seed=sc.seed, trace=True)
    sim.claims = []
    res = sim.run()
    assert res.completed == len(sc.programs) and res.lost == res.duplicated == 0
    return res, sim.claims


def test_two_origins_bursts_at_one_instant_do_not_both_take_the_one_slot() -> None:
    blind, none = _run(one_slot(claims=False))
    assert none == []
    assert [p.host for p in blind.programs if p.program_id in ("a#1", "b#3")] == ["g", "g"]  # the slot, as if free
    res, claims = _run(one_slot())
    # a, first, places at once and claims; b asks a (a has nothing held: it answers
    # with an empty claim), places on a's claim and tells a where its burst went
    assert claims == [("a", "b", True), ("b", "a", False), ("b", "a", True), ("a", "b", True)]
    hosts = {p.program_id: p.host for p in res.programs}
    assert hosts["a#1"] == "g" and hosts["b#3"] == "b"  # b counted a's claim on the slot
    latency, warmup = res_net(), one_slot().warmup
    by = {e.robot: e.t for e in res.trace if e.what == "placed" and e.t < warmup + 1}
    assert by["a"] == warmup  # first by name: at once
    assert warmup + latency <= by["b"] < warmup + 2 * latency  # as a's claim came, before its bound
    assert res.makespan < blind.makespan - 0.5


def test_an_origin_alone_waits_for_nothing_and_claims_nothing() -> None:
    sc = one_slot((SHORT, CPU))  # b submits, a does not: no teammate of b's could claim
    res, claims = _run(sc)
    assert claims == []
    placed = [e for e in res.trace if e.what == "placed"]
    assert [e.t for e in placed] == [sc.warmup] * 2  # at the instant they were submitted
    assert not [e for e in res.trace if e.what == "anomaly"]


def test_a_claim_crosses_the_wire() -> None:
    # (a node of the previous release drops it as an unknown type: tests/test_wire_golden.py)
    claim = BurstClaim(planned=True, pools=[ClaimedPool("g", "cuda", [30.0]), ClaimedPool("b", "", [1.5])])
    assert decode(encode("a", claim)).msg == claim


def test_three_origins_place_in_turn_each_after_the_claims_before_it() -> None:
    progs = [msgspec.structs.replace(p, origin=o, program=f"{p.program}-{o}") for o in ("a", "b", "c")
             for p in (SHORT, CPU)]
    sc = msgspec.structs.replace(one_slot(tuple(progs)), robots=[*one_slot().robots, RobotSpec(name="c", cores=1)])
    res, claims = _run(sc)
    # b asks a and tells c it has a burst, and waits for a's claim; c asks both and waits
    # for both; every claim goes to both others, and a answers each question
    assert sorted(claims) == sorted([("a", "b", True), ("a", "c", True), ("b", "a", False), ("b", "c", False),
                                     ("c", "a", False), ("c", "b", False), ("b", "a", True), ("b", "c", True),
                                     ("a", "b", True), ("a", "c", True), ("c", "a", True), ("c", "b", True),
                                     ("b", "c", True)])
    at = {e.robot: e.t for e in res.trace if e.what == "placed" and e.t < sc.warmup + 1}
    latency = res_net()
    assert at["a"] == sc.warmup < at["b"] < at["c"] < sc.warmup + 3 * latency
    short = {p.origin: p.host for p in res.programs if p.program_id in ("a#1", "b#3", "c#5")}
    assert short == {"a": "g", "b": "b", "c": "c"}  # the slot once; the others, seeing it taken, on cores


def test_a_node_becomes_a_submitter_with_its_first_submit_and_says_so_at_once() -> None:
    """Where no application said it connected, a robot's first program
    tells its core that it submits, and the report of the instant that
    follows tells the teammates, who then wait for its claims."""
    import random

    from ramps.core.events import PublishReport, Received, Submit
    from ramps.core.node import Node

    a = Node("a", cores=2, speed=1.0, config=RampsConfig(), rng=random.Random(1))
    b = Node("b", cores=2, speed=1.0, config=RampsConfig(), rng=random.Random(2))
    assert not a.submits and not a.current_report(with_class=True).submits
    out = a.handle(Submit(program_id="p1", program="burn", work=1.0), 1.0) + a.flush(1.0)
    [report] = [x.report for x in out if isinstance(x, PublishReport)]
    assert a.submits and report.submits
    b.handle(Received(sender="a", msg=decode(encode("a", report)).msg), 1.01)
    assert "a" in b.claims.submitters


def test_an_application_connecting_makes_its_robot_an_origin_before_its_first_program() -> None:
    """Real clients on the memory bus: two applications connect to r1 and r2
    and submit nothing yet; every teammate's core already counts them as
    origins (their first bursts will claim), and a client that only watches
    (``ramps status``, ``ramps top``) makes no robot one. It is undone by
    nothing: an origin stays one."""
    from ramps.testing.memory import MemoryTeam

    team = MemoryTeam({"r1": (2, 1.0), "r2": (2, 1.0), "r3": (2, 1.0)})
    clients = []
    try:
        team.run(3.0)
        assert [team.nodes[r].node.claims.submitters for r in ("r1", "r2", "r3")] == [set(), set(), set()]
        from ramps.runtime.client import Team
        from ramps.runtime.settings import load_settings

        s = load_settings(flags={"team": team.team}, environ={}, default_robot=False)
        clients.append(Team(s, robot="r3", timeout=1.0, transport=team.bus.transport("top"), clock=team.clock,
                            submits=False))
        clients += [team.connect("r1", "app1"), team.connect("r2", "app2")]
        team.run(1.0)
        assert [team.nodes[r].node.submits for r in ("r1", "r2", "r3")] == [True, True, False]
        assert [team.nodes[r].node.claims.submitters for r in ("r1", "r2", "r3")] == [{"r1", "r2"}] * 3
        clients.pop(1).close()
        team.run(1.0)
        assert team.nodes["r1"].node.submits
        fut = clients[-1].submit("echo", x=1)
        team.run(3.0, until=fut.done)
        assert fut.result(0) == {"x": 1}
    finally:
        for c in clients:
            c.close()
        team.close()


def _throttled(*, wait: float = 1.0, stagger: float = 0.0, robots: int = 10, seed: int = 0) -> Scenario:
    """One-core robots whose nodes handle each message up to 0.1 s late (a
    node on a throttled core), three origins bursting 2 programs each per
    3 robots, ``stagger`` seconds apart: the hosts' reports show each
    burst only after the next has been placed."""
    team = [RobotSpec(name=f"r{i:02d}", cores=1, speed=0.1, handling=0.1) for i in range(1, robots + 1)]
    per = robots // 3
    programs = [ProgramSpec(origin=f"r{o:02d}", program="burn", count=per, work=2.0, payload=50, result=100,
                            at=o * stagger) for o in range(1, 4)]
    return Scenario(name="throttled", seed=seed, robots=team, programs=programs,
                    config=RampsConfig(burst_claim_wait=wait))


def _refusals(sc: Scenario) -> tuple[int, list[int]]:
    res = Simulator(sc, seed=sc.seed).run()
    assert res.completed == sum(p.count for p in sc.programs) and res.lost == res.duplicated == 0
    return sum(s.rejections for s in res.statistics), sorted(res.distribution.values())


def test_origins_wait_for_the_answers_of_teammates_on_throttled_cores() -> None:
    """Answers that come a node's delay late are waited for: no host is offered
    two programs of one instant where it has one core. Waiting only twice the
    link's latency, the origins place blind and hosts refuse."""
    for seed in range(3):
        blind, _ = _refusals(_throttled(wait=0.0, seed=seed))
        waited, spread = _refusals(_throttled(seed=seed))
        assert blind > 0 and waited == 0
        assert spread == [0] + [1] * 9


def test_a_claim_heard_before_the_burst_still_counts(monkeypatch) -> None:
    """A claim that came 30 ms before the next origin's burst counts until the
    hosts' reports show its programs (a throttled host reports late), not only
    for the instant: dropped after twice the latency, hosts refuse."""
    import ramps.core.claims as claims

    kept, spread = _refusals(_throttled(stagger=0.03))
    assert kept == 0 and spread == [0] + [1] * 9
    monkeypatch.setattr(claims, "KEEP", 0.0)
    dropped, _ = _refusals(_throttled(stagger=0.03))
    assert dropped > 0


class _OldA(Simulator):
    """Robot a is of a release before claims: it drops them and sends none."""

    def _send(self, src, to, msg) -> None:
        if isinstance(msg, BurstClaim) and "a" in (src.spec.name, to):
            return
        super()._send(src, to, msg)


def test_a_teammate_that_never_answers_holds_a_burst_no_longer_than_the_wait() -> None:
    sc = one_slot()
    res = _OldA(sc, seed=sc.seed, trace=True).run()
    assert res.completed == len(sc.programs)
    at = max(e.t for e in res.trace if e.what == "placed" and e.robot == "b" and e.t < sc.warmup + 3)
    bound = 2 * res_net() + sc.config.burst_claim_wait
    assert sc.warmup + bound - 0.01 <= at <= sc.warmup + bound + 0.01


def test_a_burst_larger_than_a_plan_counts_the_claims_too() -> None:
    """Three origins of 26 programs each (more than ``PLAN_MAX``, placed in parts) on
    78 throttled robots: one program on every robot, no refusal."""
    from ramps.core.burst import PLAN_MAX

    sc = _throttled(robots=78)
    assert sc.programs[0].count > PLAN_MAX
    assert _refusals(sc) == (0, [1] * 78)
    assert _refusals(_throttled(robots=78, wait=0.0))[0] > 0


def test_an_offer_planned_onto_a_claimed_robot_expects_the_claimed_program_there() -> None:
    """Hosts that handle messages a second late have not reported a's programs when b, which
    has a's claims, plans its own second on each: b's offers say it expects a's program
    there, so a host that took it does not refuse b's for being busier than expected."""
    from ramps.core.messages import OffloadRequest

    class _Offers(Simulator):
        def _send(self, src, to, msg) -> None:
            if isinstance(msg, OffloadRequest):
                self.offers.append((src.spec.name, to, msg.expected_runnable))
            super()._send(src, to, msg)

    robots = ([RobotSpec(name=n, cores=1, speed=0.05) for n in ("a", "b")]
              + [RobotSpec(name=f"h{i}", cores=1, handling=1.0) for i in range(1, 5)])
    programs = [ProgramSpec(origin=o, program="burn", count=4, work=10.0, payload=50, result=100) for o in "ab"]
    sc = Scenario(name="claimed-offers", seed=1, robots=robots, programs=programs)
    sim = _Offers(sc, seed=sc.seed)
    sim.offers = []
    res = sim.run()
    assert res.completed == 8 and sorted(res.distribution.values()) == [0, 0, 2, 2, 2, 2]
    assert sorted((o, e) for o, _, e in sim.offers) == [("a", 0.0)] * 4 + [("b", 1.0)] * 4


def test_alike_programs_of_a_planned_burst_are_priced_once_a_part(monkeypatch) -> None:
    """A burst of equal programs planned with teammates' claims prices each
    candidate once for all of them (once a part of ``PLAN_MAX``), not once a
    program, and places as before: one program on every robot, no refusal."""
    from ramps.core.burst import PLAN_MAX
    from ramps.core.policy import RampsPolicy

    calls = []
    pools = RampsPolicy.pools

    def counted(self, req, *a, **kw):
        calls.append(req.program_id)
        return pools(self, req, *a, **kw)

    monkeypatch.setattr(RampsPolicy, "pools", counted)
    sc = _throttled(robots=78)
    assert _refusals(sc) == (0, [1] * 78)
    # the first origin by name has no claims to count and places one by one (no plan); the two
    # after it plan their 26 programs in two parts each
    assert len(calls) == 2 * -(-sc.programs[0].count // PLAN_MAX) == 4
