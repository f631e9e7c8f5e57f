"""The per-program path kept cheap without changing a decision.

The load server counts its bookings incrementally, the cost model inlines
processor sharing, the executor lists the work left without a full sort,
and ``report_problem`` passes a sound report in one chain of comparisons.
Each must give exactly what the straightforward code gives (the same
floats, the same counts, the same words), or the simulator's fixed-seed
sweeps would change: here each is checked against that code, kept below as
the reference, over generated inputs. The driver publishes the newest
report of the instant of a batch, once, at once, a client decodes
load reports only when ``status()`` asks for them, a program's updates to
its client wait a moment (none if its outcome goes first), its acceptance
writes nothing to the durable record, and a call's argument names are
judged without ``Signature.bind`` where the names alone tell.
"""

from __future__ import annotations

import math
import random

import msgspec
from hypothesis import given, settings
from hypothesis import strategies as st

from corehelpers import report

import ramps.runtime.node as rn
from ramps.core.config import RampsConfig
from ramps.core.cost import program_share, shared_finish_time
from ramps.core.events import Note, PublishReport
from ramps.core.executor import Executor, _Job
from ramps.core.loadview import LoadView, report_problem
from ramps.core.messages import MAX_CORES, MAX_LISTED, MAX_LOAD, MAX_SPEED, MAX_WEIGHT, MIN_SPEED, MIN_WEIGHT, decode
from ramps.core.node import Node
from ramps.runtime.settings import load_settings
from ramps.testing.memory import FakeClock


# ---------------------------------------------------------------- references (the straightforward code)
class ReferenceBookings:
    """One host's bookings as the load server kept them: every change
    followed by a full recount (a booking is [accept_seq, finish_seq])."""

    def __init__(self) -> None:
        self.bookings: dict = {}
        self.totals = (-1, -1)
        self.incarnation: int | None = None
        self.unseen_accept = self.unseen_finish = 0

    def recount(self) -> None:
        acc_total, fin_total = self.totals
        self.unseen_accept = self.unseen_finish = 0
        for key, (a, f) in list(self.bookings.items()):
            if a is None or a > acc_total:
                if f is None:
                    self.unseen_accept += 1
            elif f is not None:
                if f > fin_total:
                    self.unseen_finish += 1
                else:
                    del self.bookings[key]

    def book(self, key) -> None:
        self.bookings[key] = [None, None]
        self.unseen_accept += 1

    def accepted(self, key, seq) -> None:
        b = self.bookings.get(key)
        if b is None or b[0] is not None:
            return
        b[0] = seq
        self.recount()

    def released(self, key, seq) -> None:
        b = self.bookings.get(key)
        if b is None:
            return
        if seq is None or b[0] is None:
            del self.bookings[key]
        else:
            b[1] = seq
        self.recount()

    def report(self, incarnation, acc_total, fin_total) -> None:
        if self.incarnation is not None and incarnation != self.incarnation:
            self.bookings.clear()
        self.incarnation, self.totals = incarnation, (acc_total, fin_total)
        self.recount()


def reference_finish_time(work, others, cores, speed, background=0.0, weight=1.0) -> float:
    left = sorted(x for x in others if x < work)
    k = len(others) + 1
    t = done = 0.0
    for x in left:
        t += (x - done) / (speed * program_share(cores, k, background, weight))
        done = x
        k -= 1
    return t + (work - done) / (speed * program_share(cores, k, background, weight))


def reference_problem(rep) -> str | None:
    if not 1 <= rep.cores <= MAX_CORES:
        return f"load report from {rep.robot!r} claims {rep.cores} cores"
    for name in ("speed", "cpu_busy", "runnable", "ramps_avg", "window"):
        value = getattr(rep, name)
        if not math.isfinite(value) or not 0 <= value <= MAX_LOAD:
            return f"load report from {rep.robot!r} has {name}={value!r}"
    if not MIN_SPEED <= rep.speed <= MAX_SPEED:
        return f"load report from {rep.robot!r} claims speed {rep.speed!r}"
    if not MIN_WEIGHT <= rep.program_weight <= MAX_WEIGHT:
        return f"load report from {rep.robot!r} claims program weight {rep.program_weight!r}"
    if rep.ramps_running < 0 or rep.accepted_total < 0 or rep.finished_total < 0:
        return f"load report from {rep.robot!r} has negative counters"
    return None


# ---------------------------------------------------------------- the load server's bookings
ops = st.lists(st.tuples(st.sampled_from(["book", "accept", "release", "report", "restart"]),
                         st.integers(0, 7), st.integers(0, 40), st.booleans()), max_size=80)


@settings(max_examples=250, deadline=None)
@given(ops)
def test_bookings_count_as_a_full_recount_would(steps):
    """Bookings made (twice under one key too), accepted, released, and
    reports whose totals pass them (in order, going back, from a new
    incarnation): after every step the counts and the bookings kept are
    those of a full recount after every change."""
    view = LoadView("o", cores=4, speed=1.0)
    view.book("h", "first", 1)  # the host is known to the view from the start
    ref = ReferenceBookings()
    ref.book(("first", 1))
    seq = incarnation = acc = fin = 0
    for op, n, value, flag in steps:
        key = (f"p{n}", 1)
        if op == "book":
            view.book("h", *key)
            ref.book(key)
        elif op == "accept":
            view.accepted("h", *key, value)
            ref.accepted(key, value)
        elif op == "release":
            view.released("h", *key, None if flag else value)
            ref.released(key, None if flag else value)
        else:
            if op == "restart":
                incarnation += 1
            seq += 1
            acc, fin = (value, value // 2) if flag else (acc + value % 5, fin + value % 3)
            view.on_report(report("h", seq=seq, incarnation=incarnation, accepted_total=acc,
                                  finished_total=fin, ramps_running=3), 1.0)
            ref.report(incarnation, acc, fin)
        rob = view._robots["h"]
        assert (rob.unseen_accept, rob.unseen_finish) == (ref.unseen_accept, ref.unseen_finish)
        assert {k: [b.accept_seq, b.finish_seq] for k, b in rob.bookings.items()} == ref.bookings


# ---------------------------------------------------------------- the cost model and the work left
floats = st.floats(0.0, 100.0, allow_nan=False)


@settings(max_examples=250, deadline=None)
@given(floats.filter(lambda w: w > 0), st.lists(floats, max_size=40), st.integers(1, 16),
       st.floats(0.01, 10.0), st.sampled_from([0.0, 0.5, 1.0, 2.5, 7.0]),
       st.sampled_from([1.0, 110 / 1024, 0.5, 3.0]))
def test_shared_finish_time_is_the_same_float(work, others, cores, speed, background, weight):
    assert shared_finish_time(work, others, cores, speed, background, weight) == \
        reference_finish_time(work, others, cores, speed, background, weight)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(floats, floats), max_size=MAX_LISTED + 40))
def test_remaining_lists_the_smallest_as_a_sort_would(jobs):
    ex = Executor("h", config=RampsConfig())
    for i, (work, done) in enumerate(jobs):
        job = ex.running[(f"p{i}", 1)] = _Job("o", "noop", 0.0, work)
        job.done = done
    want = sorted(max(0.0, w - d) for w, d in jobs)[:MAX_LISTED]
    assert ex.remaining(0.0) == want


@settings(max_examples=200, deadline=None)
@given(st.lists(floats, max_size=30), st.integers(0, 40), st.floats(0.0, 5.0), floats)
def test_remaining_work_is_the_same(listed, programs, age, unknown):
    view = LoadView("o", cores=4, speed=1.0)
    view.on_report(report("h", cores=2, runnable=1.5, ramps_avg=1.0, remaining=listed), 1.0)
    left = list(listed)
    if left:
        step = ((1.0 + age) - 1.0) * 1.0 * program_share(2, len(left), 0.5, 1.0)
        left = [x - step for x in left]
    left.sort()
    if len(left) > programs:
        left = left[len(left) - programs:]
    want = [max(0.0, x) for x in left] + [unknown] * (programs - len(left))
    assert view.remaining_work("h", 1.0 + age, programs, unknown) == want


# ---------------------------------------------------------------- report_problem
odd = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-5, 10**10))


@settings(max_examples=250, deadline=None)
@given(st.fixed_dictionaries({}, optional={
    "cores": st.integers(-2, MAX_CORES + 2), "speed": odd, "cpu_busy": odd, "runnable": odd, "ramps_avg": odd,
    "window": odd, "program_weight": odd, "ramps_running": st.integers(-2, 5),
    "accepted_total": st.integers(-2, 5), "finished_total": st.integers(-2, 5)}))
def test_report_problem_says_what_it_said(fields):
    rep = report("h", **fields)
    assert report_problem(rep) == reference_problem(rep)


def test_report_problem_at_the_bounds():
    for fields in ({"speed": MIN_SPEED}, {"speed": MAX_SPEED}, {"runnable": MAX_LOAD}, {"cores": MAX_CORES},
                   {"program_weight": MIN_WEIGHT}, {"program_weight": MAX_WEIGHT}, {"speed": MIN_SPEED / 2},
                   {"cpu_busy": -0.0}, {"window": math.nextafter(MAX_LOAD, math.inf)}):
        rep = report("h", **fields)
        assert report_problem(rep) == reference_problem(rep), fields


# ---------------------------------------------------------------- the driver
class _Pub:
    def __init__(self) -> None:
        self.sent: list[bytes] = []

    def put(self, data: bytes) -> None:
        self.sent.append(data)


def test_the_newest_report_of_the_instant_of_a_batch_goes_out_at_once():
    """Reports of the instant in one batch of the core's actions: the newest
    is published, once, at once (each says all the earlier ones did: the
    executor's counters only grow; the core held them, ``Node.prompt_hold``),
    as the core made it, on the key only teammates' nodes hear. The driver
    holds none itself: nothing is due later."""
    clock = FakeClock()
    rt = rn.NodeRuntime(load_settings(flags={"robot": "r1", "team": "t"}, environ={}), clock=clock)
    rt.node = Node("r1", cores=2, speed=1.0, rng=random.Random(0))
    rt.membership.load_pub, rt.membership.prompt_pub = periodic, pub = _Pub(), _Pub()
    first, second, third = (report("r1", seq=s, accepted_total=s) for s in (1, 2, 3))
    rt.outbound.apply([PublishReport(report=first), Note(what="placed", robot="r2"), PublishReport(report=second)])
    assert len(pub.sent) == 1 and periodic.sent == []
    assert decode(pub.sent[0]).msg == second
    assert rt.outbound.held_due(clock.monotonic()) == float("inf")
    rt.outbound.apply([PublishReport(report=third)])
    assert len(pub.sent) == 2 and decode(pub.sent[1]).msg == third
    rt.outbound.apply([Note(what="placed", robot="r2")])
    clock.advance(1.0)
    rt.outbound.flush_held(clock.monotonic())
    assert len(pub.sent) == 2 and rt.membership.newest == pub.sent[1]  # nothing changed: nothing more


def test_reports_of_the_instant_reach_the_nodes_not_the_clients():
    """A host's reports of the instant reach its teammates' nodes (their
    views count its programs at once), not an application's client, which
    hears the periodic reports only."""
    from ramps.runtime import keys
    from ramps.testing.memory import MemoryTeam

    team = MemoryTeam({"r1": (2, 1.0), "r2": (2, 1.0)})
    try:
        team.run(3.0)
        heard: list = []
        team.bus.transport("watcher").subscribe(keys.load(team.team), lambda data: heard.append(decode(data).msg))
        t, out = _collector(team)
        _submit(team, t, 1, robot="r2")
        team.run(3.0, until=lambda: bool(out))
        team.run(0.05)
        assert out and out[-1].host == "r2"
        assert team.nodes["r1"].node.view._robots["r2"].report.window == 0.0  # r1 heard r2's of the instant
        team.run(3.0)
        assert heard and all(r.window > 0 for r in heard)  # periodic reports only (an instant's says window 0)
    finally:
        team.close()


def test_a_client_decodes_load_reports_only_when_asked_for_the_team():
    """A client keeps each robot's newest load report as it came and
    decodes it in ``status()``: the newest wins, garbage on the load key is
    dropped, and a newest report that is malformed leaves the one decoded
    before."""
    from ramps.core.messages import encode
    from ramps.runtime import keys
    from ramps.testing.memory import MemoryTeam

    team = MemoryTeam({"r1": (2, 1.0)})
    client = team.connect("r1")
    try:
        other = team.bus.transport("r9")
        put = lambda data: other.put(keys.load(team.team, "r9"), data)  # noqa: E731
        put(encode("r9", report("r9", seq=1, cores=3)))
        put(encode("r9", report("r9", seq=2, cores=5)))
        put(b"\x93garbage")
        assert client._reports.raw["r9"][0] != b"\x93garbage"  # nothing decoded yet, garbage not kept
        [r9] = [r for r in client.status().robots if r.robot == "r9"]
        assert r9.cores == 5 and client._reports.raw == {}
        put(encode("r9", report("r9", seq=3, cores=0)))  # out of bounds: refused when decoded
        [r9] = [r for r in client.status().robots if r.robot == "r9"]
        assert r9.cores == 5
    finally:
        client.close()
        team.close()


def test_the_cpu_benchmark_runs_its_bursts_to_the_end():
    """``python -m ramps.bench.dispatchcpu``, small: every program delivered,
    in the core alone and through the drivers and a client in memory."""
    from ramps.bench.dispatchcpu import core_burst, driver_burst

    core = core_burst(40, 8)
    assert sum(core["ran_on"].values()) == 40 and core["cpu_us_per_program"] > 0
    drv = driver_burst(40, 8)
    assert sum(drv["burst_ran_on"].values()) == 40 and sum(drv["one_at_a_time_ran_on"].values()) == 8
    assert "?" not in drv["burst_ran_on"]


# ---------------------------------------------------------------- what a program sends and writes
def _collector(team, name="app"):
    """A client on the bus that keeps what its node sends it, decoded."""
    from ramps.runtime import keys

    heard: list = []
    t = team.bus.transport(name)
    t.subscribe(keys.client(team.team, name), lambda data: heard.append(decode(data).msg))
    return t, heard


def _submit(team, t, rid: int, name="app", robot="r1", **fields):
    from ramps.core.messages import SubmitProgram, encode
    from ramps.runtime import keys

    t.put(keys.inbox(team.team, robot), encode(name, SubmitProgram(client=name, request_id=rid, program="echo",
                                                                   args=msgspec.msgpack.encode({"x": rid}),
                                                                   **fields)), block=True)


def test_a_program_that_ends_within_the_hold_sends_its_client_no_update():
    """A client's updates wait ``UPDATE_HOLD``: a program whose outcome comes
    first sends none (the outcome says all of it); one still running then
    sends one, its newest state; a request asked again is answered at once."""
    from ramps.core.messages import ProgramOutcome, ProgramUpdate
    from ramps.runtime.node_clients import UPDATE_HOLD
    from ramps.testing.memory import MemoryTeam

    team = MemoryTeam({"r1": (2, 1.0), "r2": (2, 1.0)})
    try:
        team.run(3.0)
        t, heard = _collector(team)
        _submit(team, t, 1)
        team.run(UPDATE_HOLD / 2, until=lambda: any(isinstance(m, ProgramOutcome) for m in heard))
        team.run(2 * UPDATE_HOLD)
        assert [type(m) for m in heard] == [ProgramOutcome]
        heard.clear()
        _submit(team, t, 2)
        team.run(UPDATE_HOLD / 2, complete=False)
        assert heard == []
        team.run(2 * UPDATE_HOLD, complete=False)
        assert [(type(m), m.state) for m in heard] == [(ProgramUpdate, "running")]
        _submit(team, t, 2)  # asked again: where it stands, now
        team.step()
        assert [m.state for m in heard] == ["running", "running"]
        team.run(2.0)
        assert [type(m) for m in heard][-1] is ProgramOutcome
    finally:
        team.close()


def test_an_acceptance_alone_writes_nothing_to_the_record(tmp_path):
    """The durable record is written when a program is placed and when it is
    delivered: its acceptance changes nothing a restart reads."""
    from ramps.core.durable import OriginRecord, same_to_restore
    from ramps.core.events import Submit
    from ramps.core.messages import ProgramOutcome
    from ramps.testing.memory import MemoryTeam

    sub = Submit(program_id="p", program="echo")
    offered = OriginRecord(submit=sub, attempt=1, host="r2", live={1: "r2"}, made=1, ran_on=["r3"])
    running = msgspec.structs.replace(offered, state="running", ran_on=["r3", "r2"])
    assert same_to_restore(offered, running) and same_to_restore(offered, offered)
    assert not same_to_restore(offered, msgspec.structs.replace(running, ran_on=["r2"]))
    assert not same_to_restore(offered, msgspec.structs.replace(running, attempt=2, live={2: "r2"}))
    assert not same_to_restore(offered, msgspec.structs.replace(offered, checkpoint=b"s", checkpoint_fraction=0.5))

    team = MemoryTeam({"r1": (1, 1.0), "r2": (4, 4.0)}, settings={"state_dir": str(tmp_path)})
    try:
        team.run(3.0)
        t, heard = _collector(team)
        store = team.nodes["r1"].store
        before = store.writes
        _submit(team, t, 1, work=20.0)  # heavy: offloaded to the faster robot
        team.run(30.0, until=lambda: any(isinstance(m, ProgramOutcome) for m in heard))
        [out] = [m for m in heard if isinstance(m, ProgramOutcome)]
        assert out.ok and out.host == "r2"
        assert store.writes - before == 2  # placed, delivered
        assert store.programs() == 0
    finally:
        team.close()


@settings(max_examples=200, deadline=None)
@given(st.sets(st.sampled_from(["a", "b", "c", "d", "kw"]), max_size=5))
def test_arguments_are_judged_as_signature_bind_judges_them(names):
    import inspect

    from ramps.runtime.argtypes import ArgTypes

    def f0(): ...
    def f1(a, b=1): ...
    def f2(a, *, c, d=2): ...
    def f3(a, /, b=1): ...
    def f4(a=1, **kw): ...
    def f5(*args, a, b=2): ...

    kwargs = dict.fromkeys(names, 1)
    for fn in (f0, f1, f2, f3, f4, f5):
        try:
            inspect.signature(fn).bind(**kwargs)
            want = None
        except TypeError as exc:
            want = str(exc)
        try:
            ArgTypes(fn).check(kwargs)
            got = None
        except TypeError as exc:
            got = str(exc)
        assert got == want, fn.__name__


def test_the_dispatch_benchmark_sets_its_figures_beside_a_saved_baseline():
    """``ramps bench dispatch`` compares with fe693da's and 0.1.0's saved
    runs (medians of each): a ratio per figure, which way is better."""
    from ramps.bench import dispatch as d

    for name in d.BASELINES:
        base = d.load_baseline(name)
        assert len(base["runs"]) >= 3 and base["commit"] and base["note"]
        figs = d.baseline_figures(base)
        assert all(v > 0 for v in figs.values())
    run = {"p50_ms": 0.5, "remote_p50_ms": 2.0, "throughput_per_s": 5000.0, "burst_cpu_us": {"r1": 200.0, "c": 100.0}}
    vs = d.compare(run, {"runs": [dict(run, p50_ms=1.0, throughput_per_s=2500.0), dict(run, p50_ms=0.8),
                                   dict(run, p50_ms=2.0, throughput_per_s=1000.0)]})
    assert vs["p50_ms"] == {"this": 0.5, "baseline": 1.0, "ratio": 0.5, "better": True}
    assert vs["throughput_per_s"]["ratio"] == 2.0 and vs["throughput_per_s"]["better"]
    assert vs["remote_p50_ms"]["ratio"] == 1.0 and vs["cpu_us"]["this"] == 300.0
