"""Pure tests of ``ramps.core``: cost model, wire format, load view and
policies, with no simulator.

How this works: a ``Team`` joins two to five ``Node`` objects with an
in-memory, zero-latency network: a list of messages in flight, an explicit
``now`` and a set of robots whose links are cut. Tests step it by hand, so
each reads as a scenario: submit, deliver, advance the clock, finish a
program, look at the actions. Nothing sleeps and nothing is random except
the nodes' own seeded generators.

Rules: assert on actions and on ``statistics()``-level state, never on timing
of the machine running the tests. Known bugs are ``xfail(strict=True)`` with
the reason starting "BUG:".
"""

from __future__ import annotations

import random
import typing
from collections import Counter

import msgspec
import pytest

from hypothesis import given
from hypothesis import strategies as st

from ramps.core.cost import (
    NetworkEstimate,
    comm_time,
    compute_time,
    nice_weight,
    program_share,
    share,
    weighted_shares,
)
from ramps.core.loadview import LoadView, report_problem
from ramps.core.messages import (
    MAX_MESSAGE_BYTES,
    MAX_NAME,
    MAX_TEXT,
    PROTOCOL_VERSION,
    BurstClaim,
    CancelProgram,
    CancelSubmitted,
    ClaimedPool,
    Heartbeat,
    LinkProbe,
    LinkProbeReply,
    ProgramCheckpoint,
    Message,
    OffloadAccepted,
    OffloadRejected,
    OffloadRequest,
    ProgramOutcome,
    ProgramProgress,
    ProgramRef,
    ProgramResult,
    ProgramUpdate,
    ResultAck,
    SubmitProgram,
    WireError,
    decode,
    encode,
)
from ramps.core.policy import POLICIES, RampsPolicy, make_policy

from corehelpers import choose, report, view_of


# =================================================================== cost model
@pytest.mark.parametrize("cores, runnable, expected", [
    (4, 0, 1.0), (4, 3, 1.0), (4, 7, 0.5), (1, 1, 0.5), (2, 0, 1.0), (1, 9, 0.1), (4, 4.5, 4 / 5.5),
])
def test_share(cores, runnable, expected) -> None:
    assert share(cores, runnable) == pytest.approx(expected)


@pytest.mark.parametrize("work, cores, speed, runnable, expected", [
    (53.0, 1, 1.0, 0, 53.0),
    (53.0, 4, 1.0, 3, 53.0),      # a free core is as good as an idle robot
    (53.0, 4, 1.0, 7, 106.0),     # 8 tasks on 4 cores: half a core each
    (10.0, 2, 2.0, 3, 10.0),      # half a core at twice the speed
    (60.0, 1, 0.5, 2, 360.0),
])
def test_compute_time(work, cores, speed, runnable, expected) -> None:
    assert compute_time(work, cores, speed, runnable) == pytest.approx(expected)


def test_comm_time() -> None:
    assert comm_time(1000, 1000, NetworkEstimate(latency=0.005, bandwidth=2.5e6)) == pytest.approx(0.0158)
    assert comm_time(0, 0, NetworkEstimate(latency=0.1, bandwidth=1.0)) == pytest.approx(0.3)
    assert comm_time(2_000_000, 500_000, NetworkEstimate(latency=0.0, bandwidth=2.5e6)) == pytest.approx(1.0)


# =================================================================== wire format
SAMPLES: list[Message] = [
    report("r1", seq=7, cores=2, speed=1.5, cpu_busy=1.25, runnable=3.5, ramps_running=2, ramps_avg=1.75,
           accepted_total=9, finished_total=7, window=1.0, mem_free=1 << 30),
    OffloadRequest(program_id="o#1", attempt=2, origin="o", host="r1", program="route_plan", args=b"\x00\xffxy",
                   payload_size=4, work=53.0, expected_runnable=1.5, force=True),
    OffloadAccepted(program_id="o#1", attempt=2, host="r1", accept_seq=10),
    OffloadRejected(program_id="o#1", attempt=2, host="r1", reason="busy", permanent=False, detail="4 runnable",
                    report=report("r1", seq=8)),
    Heartbeat(host="r1", incarnation=3, programs=[ProgramRef("o#1", 2), ProgramRef("o#2", 1)]),
    ProgramResult(program_id="o#1", attempt=2, host="r1", ok=False, value=b"v", error="boom", result_size=1,
                  retryable=True, finish_seq=8),
    ResultAck(program_id="o#1", attempt=2, origin="o"),
    CancelProgram(program_id="o#1", attempt=2, origin="o"),
    SubmitProgram(client="o/app-1", request_id=5, program="route_plan", args=b"\x81", work=2.0, result_size=10,
                  local_only=True),
    CancelSubmitted(client="o/app-1", request_id=5),
    ProgramOutcome(request_id=5, ok=False, error="boom", error_kind="program", host="r1", attempts=2),
    ProgramProgress(program_id="o#1", attempt=2, host="r1", fraction=0.4, detail="row 12 of 30"),
    ProgramUpdate(request_id=5, state="progress", host="r1", attempt=2, fraction=0.4, detail="row 12 of 30"),
    LinkProbe(sent_at=12.5, padding=b"\0" * 64),
    LinkProbeReply(sent_at=12.5, size=64),
    BurstClaim(planned=True, pools=[ClaimedPool("r1", "cuda", [30.0, 10.0]), ClaimedPool("r2", "", [1.5])]),
    ProgramCheckpoint(program_id="o#1", attempt=2, host="r1", state=b"\x82\xa1i\x0c", fraction=0.4),
]


def test_samples_cover_every_message_type() -> None:
    assert {type(m) for m in SAMPLES} == set(typing.get_args(Message))


@pytest.mark.parametrize("msg", SAMPLES, ids=lambda m: type(m).__name__)
def test_wire_round_trip(msg: Message) -> None:
    env = decode(encode("r1", msg))
    assert env.v == PROTOCOL_VERSION
    assert env.sender == "r1"
    assert env.msg == msg
    assert type(env.msg) is type(msg)


def _raw(v: int = PROTOCOL_VERSION, sender: str = "a", **msg) -> bytes:
    body = msg or {"type": "ack", "program_id": "p", "attempt": 1, "origin": "o"}
    return msgspec.msgpack.encode({"v": v, "sender": sender, "msg": body})


def test_version_mismatch_names_both_versions() -> None:
    other = PROTOCOL_VERSION + 41
    with pytest.raises(WireError) as info:
        decode(_raw(v=other))
    text = str(info.value)
    assert f"version {other}" in text
    assert f"version {PROTOCOL_VERSION}" in text


def test_version_is_checked_before_the_body() -> None:
    # a future version may have a body we cannot parse: still a version error
    with pytest.raises(WireError, match="version"):
        decode(_raw(v=PROTOCOL_VERSION + 1, type="hologram", payload=[1, 2, 3]))


def test_oversized_message_rejected_before_parsing() -> None:
    # garbage would say "not a ramps message" if it were parsed; the size check comes first
    with pytest.raises(WireError, match="exceeds the limit"):
        decode(b"\xc1" * 101, max_bytes=100)
    good = encode("a", SAMPLES[1])
    with pytest.raises(WireError, match=f"{len(good)} bytes exceeds the limit of {len(good) - 1}"):
        decode(good, max_bytes=len(good) - 1)
    assert decode(good, max_bytes=len(good)).msg == SAMPLES[1]
    assert MAX_MESSAGE_BYTES >= 1 << 20


@pytest.mark.parametrize("data", [
    b"", b"\xc1", b"garbage bytes", b"\x93\x01\x02\x03", bytes(range(256)),
    msgspec.msgpack.encode([1, "a", {}]),
    msgspec.msgpack.encode({"v": "one", "sender": "a"}),
    _raw(type="hologram"),                                               # unknown message tag
    _raw(type="ack", program_id="p", attempt="first", origin="o"),       # wrong type
    _raw(type="ack", program_id="p", origin="o"),                        # missing field
], ids=lambda d: repr(d[:12]))
def test_garbage_is_a_wire_error(data: bytes) -> None:
    with pytest.raises(WireError):
        decode(data)


def test_wire_error_is_a_value_error() -> None:
    assert issubclass(WireError, ValueError)


@pytest.mark.parametrize("sender, msg", [
    ("x" * (MAX_NAME + 1), ResultAck(program_id="p", attempt=1, origin="o")),
    ("", ResultAck(program_id="p", attempt=1, origin="o")),
    ("a", ResultAck(program_id="p" * (MAX_NAME + 1), attempt=1, origin="o")),
    ("a", OffloadRequest(program_id="p", attempt=1, origin="o", host="h", program="n" * (MAX_NAME + 1))),
    ("a", OffloadAccepted(program_id="p", attempt=1, host="h" * (MAX_NAME + 1), accept_seq=1)),
    ("a", report("r" * (MAX_NAME + 1))),
    ("a", ResultAck(program_id="p", attempt=1, origin="")),
    ("a", ProgramResult(program_id="p", attempt=1, host="h", ok=False, error="e" * (MAX_TEXT + 1))),
])
def test_out_of_bounds_names_and_texts_rejected(sender: str, msg: Message) -> None:
    with pytest.raises(WireError, match="out of bounds|longer than"):
        decode(encode(sender, msg))


def test_names_at_the_limit_accepted() -> None:
    msg = OffloadAccepted(program_id="p" * MAX_NAME, attempt=1, host="h" * MAX_NAME, accept_seq=1)
    assert decode(encode("s" * MAX_NAME, msg)).msg == msg


# =================================================================== load view
def test_ramps_reading_counts_a_booking_until_a_report_covers_it() -> None:
    view = view_of("o", report("a", seq=1))
    assert view.ramps_programs("a") == 0
    view.book("a", "p", 1)
    assert view.ramps_programs("a") == 1
    view.accepted("a", "p", 1, accept_seq=1)
    assert view.ramps_programs("a") == 1
    # a report measured before the program arrived does not include it
    view.on_report(report("a", seq=2, accepted_total=0, ramps_running=0), 1.0)
    assert view.ramps_programs("a") == 1
    # one that covers the acceptance: now the report's own count is the truth
    view.on_report(report("a", seq=3, accepted_total=1, ramps_running=1), 2.0)
    assert view.ramps_programs("a") == 1
    view.on_report(report("a", seq=4, accepted_total=3, ramps_running=3), 3.0)  # others' programs too
    assert view.ramps_programs("a") == 3


def test_ramps_reading_subtracts_finished_programs_not_yet_reported() -> None:
    view = view_of("o", report("a", seq=1))
    view.book("a", "p", 1)
    view.accepted("a", "p", 1, accept_seq=1)
    view.on_report(report("a", seq=2, accepted_total=1, ramps_running=1), 1.0)
    view.released("a", "p", 1, finish_seq=1)
    assert view.ramps_programs("a") == 0  # the report still shows it running
    view.on_report(report("a", seq=3, accepted_total=1, finished_total=0, ramps_running=1), 2.0)
    assert view.ramps_programs("a") == 0
    view.on_report(report("a", seq=4, accepted_total=1, finished_total=1, ramps_running=0), 3.0)
    assert view.ramps_programs("a") == 0  # no longer subtracted: the report shows it gone


def test_booking_released_before_acceptance_is_forgotten() -> None:
    view = view_of("o", report("a", seq=1))
    view.book("a", "p", 1)
    view.released("a", "p", 1, finish_seq=None)  # rejected or host failed
    assert view.ramps_programs("a") == 0


def test_finished_program_not_counted_before_any_report_shows_it() -> None:
    view = view_of("o", report("a", seq=1))
    view.book("a", "p", 1)
    view.accepted("a", "p", 1, accept_seq=1)
    view.released("a", "p", 1, finish_seq=1)  # the program ended before a's next report
    assert view.ramps_programs("a") == 0


def test_new_incarnation_drops_bookings() -> None:
    view = view_of("o", report("a", seq=5))
    view.book("a", "p", 1)
    view.on_report(report("a", seq=1, incarnation=1), 1.0)
    assert view.ramps_programs("a") == 0


def test_paper_reading_bookings_reset_by_next_report() -> None:
    view = view_of("o", report("a", seq=1, cpu_busy=1.0))
    view.book("a", "p", 1)
    view.book("a", "q", 1)
    assert view.paper_load("a") == pytest.approx(3.0)
    # the next report was measured before the programs started: the paper's
    # load server forgets the bookings all the same
    view.on_report(report("a", seq=2, cpu_busy=0.5), 1.0)
    assert view.paper_load("a") == pytest.approx(0.5)
    assert view.ramps_programs("a") == 2  # ramps' reading keeps them


def test_blacklist_lifted_only_by_a_newer_report() -> None:
    view = view_of("o", report("a", seq=5), report("b", seq=1))
    assert view.blacklist("a") is True
    assert view.blacklist("a") is False
    assert view.is_blacklisted("a") and view.blacklisted() == ["a"]
    assert "a" not in view.candidates(1.0)
    assert view.on_report(report("a", seq=5), 1.0) is False  # duplicate
    assert view.on_report(report("a", seq=4), 1.0) is False  # older
    assert view.on_report(report("a", seq=5), 1.0, fresh=True) is False  # same seq, even fresh
    assert view.is_blacklisted("a")
    assert view.on_report(report("a", seq=6), 2.0) is True
    assert not view.is_blacklisted("a") and "a" in view.candidates(2.0)


def test_blacklist_lifted_by_a_new_incarnation() -> None:
    view = view_of("o", report("a", seq=40))
    view.blacklist("a")
    assert view.on_report(report("a", seq=1, incarnation=1), 1.0) is True
    assert not view.is_blacklisted("a")


def test_blacklist_of_a_robot_never_heard_from() -> None:
    view = view_of("o")
    assert view.blacklist("ghost") is True
    assert view.on_report(report("ghost", seq=1), 1.0) is True


def test_own_robot_is_never_blacklisted() -> None:
    view = view_of("o", report("o"))
    assert view.blacklist("o") is False
    assert view.candidates(1.0)[0] == "o"


def test_duplicate_and_older_reports_ignored() -> None:
    view = view_of("o", report("a", seq=3, runnable=2.0))
    received = view.reports_received
    view.on_report(report("a", seq=3, runnable=9.0), 1.0)
    view.on_report(report("a", seq=2, runnable=9.0), 1.0)
    assert view.report_of("a").runnable == 2.0
    assert view.reports_received == received
    assert view.report_age("a", 1.5) == pytest.approx(1.0)  # arrival time of the kept one


def test_fresh_report_replaces_one_with_the_same_seq() -> None:
    view = view_of("o", report("a", seq=3, runnable=2.0))
    view.on_report(report("a", seq=3, runnable=6.0, window=0.0), 1.0, fresh=True)
    assert view.report_of("a").runnable == 6.0
    view.on_report(report("a", seq=2, runnable=0.0), 1.0, fresh=True)  # older: still ignored
    assert view.report_of("a").runnable == 6.0


def test_candidates_skip_stale_and_lost_robots() -> None:
    view = LoadView("o", cores=1, speed=1.0, max_report_age=10.0)
    view.on_report(report("a"), 0.0)
    view.on_report(report("b"), 5.0)
    assert view.candidates(9.0) == ["o", "a", "b"]
    assert view.candidates(12.0) == ["o", "b"]
    view.set_lost("b", True)
    assert view.candidates(12.0) == ["o"]
    view.set_lost("b", False)
    assert view.candidates(12.0) == ["o", "b"]


# =================================================================== policies
def test_policies_are_the_five_of_the_paper_and_ours() -> None:
    assert set(POLICIES) == {"ramps", "paper", "round_robin", "random", "local_only"}
    with pytest.raises(ValueError, match="unknown policy 'best'"):
        make_policy("best")


@pytest.mark.parametrize("cores", [1, 4])
@pytest.mark.parametrize("seed", range(5))
def test_ramps_spreads_five_programs_over_five_idle_robots(cores: int, seed: int) -> None:
    names = ["r0", "r1", "r2", "r3", "r4"]
    view = view_of("r0", *(report(n, cores=cores) for n in names), cores=cores)
    policy, rng = make_policy("ramps"), random.Random(seed)
    hosts = []
    for i in range(5):
        host = choose(policy, view, rng=rng)
        view.book(host, f"p{i}", 1)
        hosts.append(host)
    assert sorted(hosts) == names, hosts
    assert hosts[0] == "r0"  # all equal: the local robot wins the tie


@pytest.mark.parametrize("seed", range(5))
def test_ramps_avoids_a_robot_with_background_load_while_others_have_free_cores(seed: int) -> None:
    view = view_of("o", report("o", cores=2), report("stressed", cores=4, cpu_busy=4.0, runnable=8.0),
                   report("b", cores=4), report("c", cores=4), cores=2)
    policy, rng = make_policy("ramps"), random.Random(seed)
    hosts = []
    for i in range(10):  # o, b and c have 2 + 4 + 4 free cores
        host = choose(policy, view, rng=rng)
        view.book(host, f"p{i}", 1)
        hosts.append(host)
    assert "stressed" not in hosts
    assert Counter(hosts) == {"o": 2, "b": 4, "c": 4}


def test_paper_policy_treats_any_saturated_robot_alike() -> None:
    # 'stressed' runs 8 background processes, 'full' four programs: both
    # report 100% CPU, which is all the paper's load server sees
    reports = (report("o", cores=1, speed=0.5, cpu_busy=1.0, runnable=1.0),
               report("stressed", cores=4, cpu_busy=4.0, runnable=8.0),
               report("full", cores=4, cpu_busy=4.0, runnable=4.0, ramps_running=4, ramps_avg=4.0))
    view = view_of("o", *reports, cores=1, speed=0.5)
    assert view.paper_load("stressed") == view.paper_load("full")
    picks = Counter(choose(make_policy("paper"), view, seed=s) for s in range(40))
    assert set(picks) == {"stressed", "full"}, picks
    # ramps sees the difference: 8 tasks on 4 cores is worse than 4 on 4
    assert {choose(make_policy("ramps"), view, seed=s) for s in range(20)} == {"full"}


def test_round_robin_cycles_starting_at_the_origin() -> None:
    view = view_of("o", report("o"), report("c"), report("a"), report("b"))
    policy = make_policy("round_robin")
    assert [choose(policy, view) for _ in range(8)] == ["o", "a", "b", "c", "o", "a", "b", "c"]


def test_round_robin_skips_blacklisted_robots() -> None:
    view = view_of("o", report("o"), report("a"), report("b"))
    view.blacklist("a")
    policy = make_policy("round_robin")
    assert [choose(policy, view) for _ in range(4)] == ["o", "b", "o", "b"]


def test_local_only_stays_home_however_busy() -> None:
    view = view_of("o", report("o", cores=1, cpu_busy=1.0, runnable=50.0), report("a", cores=16), cores=1)
    policy = make_policy("local_only")
    assert {choose(policy, view, seed=s) for s in range(10)} == {"o"}


def test_random_policy_is_seeded_and_uses_every_candidate() -> None:
    view = view_of("o", report("o"), report("a"), report("b"))
    picks = [choose(make_policy("random"), view, seed=s) for s in range(40)]
    assert set(picks) == {"o", "a", "b"}
    assert picks == [choose(make_policy("random"), view, seed=s) for s in range(40)]


@pytest.mark.parametrize("name", sorted(POLICIES))
def test_no_policy_chooses_a_blacklisted_or_lost_robot(name: str) -> None:
    view = view_of("o", report("o", cores=1, runnable=30.0, cpu_busy=1.0),
                   report("a", cores=8, speed=4.0), report("b", cores=8, speed=4.0), report("c"), cores=1)
    view.blacklist("a")
    view.set_lost("b", True)
    policy = make_policy(name)
    rng = random.Random(1)
    assert {choose(policy, view, rng=rng) for _ in range(30)} <= {"o", "c"}


def test_ramps_exclude_moves_the_choice_but_never_empties_it() -> None:
    view = view_of("o", report("o", cores=1, runnable=30.0), report("a", speed=2.0), report("b"), cores=1)
    policy = make_policy("ramps")
    assert choose(policy, view) == "a"
    assert choose(policy, view, exclude=frozenset({"a"})) == "b"
    assert choose(policy, view, exclude=frozenset({"a", "b"})) == "o"
    assert choose(policy, view, exclude=frozenset({"a", "b", "o"})) == "a"


# ------------------------------------------------------------- weighted sharing
def test_nice_weights_are_the_kernels() -> None:
    assert nice_weight(0) == 1.0
    assert nice_weight(10) == pytest.approx(110 / 1024)
    assert nice_weight(19) == pytest.approx(15 / 1024)
    assert nice_weight(-20) == pytest.approx(88761 / 1024)
    with pytest.raises(ValueError):
        nice_weight(20)


@pytest.mark.parametrize("cores, programs, background, weight, expected", [
    (4, 1, 0, 0.1, 1.0),                  # a free core is a free core, whatever the weight
    (4, 2, 2, 0.1, 1.0),
    (1, 1, 1, 110 / 1024, 110 / 1134),    # CFS: nice 10 next to nice 0 on one core gets 9.7%
    (2, 2, 1, 0.1, 0.5),                  # the busy task has a core, the two programs share the other
    (4, 5, 3, 0.1, 0.2),                  # 3 cores busy, 5 programs share the fourth
    (4, 5, 3, 0.5, 0.5 * 4 / 5.5),        # at half weight the busy tasks do not fill their cores
    (4, 3, 6, 0.5, 4 * 0.5 / 7.5),        # nobody has a whole core
    (2, 3, 1, 2.0, 2 * 2.0 / 7.0),        # heavier programs, still nobody has a core
    (4, 2, 4, 4.0, 1.0),                  # heavier programs each get a core
])
def test_program_share(cores, programs, background, weight, expected) -> None:
    assert program_share(cores, programs, background, weight) == pytest.approx(expected)


def _water_fill(cores: float, programs: int, background: float, weight: float) -> float:
    """Reference: bisect for the rate per unit weight that fills min(cores, tasks)
    with no task above a core; a program's share is then that rate times its weight."""
    def used(lam: float) -> float:
        return programs * min(1.0, lam * weight) + background * min(1.0, lam)

    target = min(cores, programs + background)
    lo, hi = 0.0, 1e6
    for _ in range(200):
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if used(mid) < target else (lo, mid)
    return min(1.0, hi * weight)


@given(cores=st.integers(1, 16), programs=st.integers(1, 40), background=st.floats(0, 40),
       weight=st.sampled_from([nice_weight(n) for n in range(-5, 20)]))
def test_program_share_is_weighted_water_filling(cores, programs, background, weight) -> None:
    assert program_share(cores, programs, background, weight) == pytest.approx(
        _water_fill(cores, programs, background, weight), rel=1e-6, abs=1e-9)


def test_equal_weights_are_the_papers_model() -> None:
    for cores in (1, 2, 4):
        for ramps in range(0, 10):
            for bg in (0, 0.5, 3, 8):
                assert program_share(cores, ramps + 1, bg, 1.0) == pytest.approx(share(cores, ramps + bg))


def test_ramps_counts_that_a_busy_robots_own_software_comes_first() -> None:
    """'busy' has 4 cores with 3.5 runnable processes of its own. At equal
    weights a program would get 0.89 of a core there and 'busy' (speed 1)
    beats the idle but slow 'slow' (speed 0.6). Its workers at nice 10
    really get the half core the busy software leaves, so 'slow' is faster."""
    def pick(weight: float) -> str:
        view = view_of("o", report("o", cores=1, runnable=6.0),
                       report("busy", cores=4, cpu_busy=3.5, runnable=3.5, program_weight=weight),
                       report("slow", cores=4, speed=0.6), cores=1)
        return choose(RampsPolicy(), view, work=50.0)

    assert pick(1.0) == "busy"
    assert pick(nice_weight(10)) == "slow"


def test_a_load_report_with_an_impossible_program_weight_is_refused() -> None:
    with pytest.raises(WireError, match="program_weight"):
        decode(encode("a", report("a", program_weight=0.0)))
    assert report_problem(report("a", program_weight=1e6)) is not None
    assert report_problem(report("a", program_weight=nice_weight(10))) is None
    view = view_of("o")
    view.on_report(report("a", program_weight=float("nan")), 1.0)
    assert view.bad_reports == 1 and view.candidates(1.0) == ["o"]


@given(cores=st.integers(1, 16), weights=st.lists(st.sampled_from([nice_weight(n) for n in (0, 5, 10, 19)]),
                                                  min_size=1, max_size=30))
def test_weighted_shares_fill_the_cores_by_weight(cores, weights) -> None:
    shares, level = weighted_shares(cores, weights)
    assert all(0.0 < s <= 1.0 + 1e-9 for s in shares)
    assert sum(shares) == pytest.approx(min(cores, len(weights)))
    for w, s in zip(weights, shares):  # below a core: in proportion to weight
        assert s == pytest.approx(1.0) or s == pytest.approx(w * level)
    # the two-class case is program_share's
    progs = [w for w in weights if w == weights[0]]
    if len(set(weights)) <= 2 and weights[0] <= 1.0:
        others = [w for w in weights if w != weights[0]]
        if all(w == 1.0 for w in others):
            assert shares[0] == pytest.approx(program_share(cores, len(progs), len(others), weights[0]))
