"""The node driver's own clock and its view of teammates after a stall
(``ramps.runtime.node.NodeRuntime._clock`` / ``Inbound.on_liveliness``), without
Zenoh or processes: an injected fake clock, an in-memory transport and the
real core ``Node``. Whole teams of real drivers: tests/test_driver_memory.py.
The end-to-end version (SIGSTOP of a real node) is tests/test_busy_node_e2e.py."""

from __future__ import annotations

import random

import pytest

from corehelpers import report

import ramps.runtime.node as rn
import ramps.runtime.node_clients as node_clients
from ramps.core.events import Note, PublishReport, Received
from ramps.core.node import Node
from ramps.runtime.settings import load_settings
from ramps.testing.memory import FakeClock, MemoryBus


def wait(rt, fake: FakeClock, seconds: float) -> None:
    """The driver sleeps ``seconds`` because it chose to (not a stall)."""
    rt.awake.sleep_until = fake.t + seconds
    fake.t += seconds


@pytest.fixture
def driver():
    fake = FakeClock()
    rt = rn.NodeRuntime(load_settings(flags={"robot": "r1", "team": "t"}, environ={}), clock=fake)
    rt.node = Node("r1", cores=2, speed=1.0, rng=random.Random(0))
    for r in ("r2", "r3"):  # teammates the load server knows
        rt.node.handle(Received(sender=r, msg=report(r)), fake.t)
    rt.awake.last_read = fake.t
    return rt, fake


def test_a_wait_the_driver_chose_is_not_a_stall_but_a_late_wake_is(driver):
    rt, fake = driver
    now0 = rt._clock()
    rt.awake.sleep_until = fake.t + 2.0  # the driver sleeps 2 s until its next deadline
    fake.t += 2.2  # woke a little late: normal jitter
    assert rt._clock() == pytest.approx(now0 + 2.2) and rt.awake.stalls == 0
    rt.awake.sleep_until = fake.t + 1.0
    fake.t += 6.0  # frozen 5 s past its wake-up
    now = rt._clock()
    assert rt.awake.stalls == 1 and rt.awake.stalled_s == pytest.approx(5.0)
    assert now == pytest.approx(now0 + 2.2 + 1.0)  # the core never sees the 5 s
    fake.t += 0.3  # handling items back to back: no stall
    assert rt._clock() == pytest.approx(now + 0.3) and rt.awake.stalls == 1


def test_teammates_lost_right_after_a_stall_are_held_and_forgotten_if_back(driver):
    rt, fake = driver
    rt._clock()
    rt.awake.sleep_until = fake.t
    fake.t += 4.0
    now = rt._clock()  # a 4 s stall
    assert rt.inbound.on_liveliness("r2", False, now) == []  # held, not yet a loss
    assert not rt.node.view.is_lost("r2")
    wait(rt, fake, 0.2)
    back = rt.inbound.on_liveliness("r2", True, rt._clock())  # back: both forgotten
    assert [type(a) for a in back] == [PublishReport]  # and it hears this robot's load at once
    assert rt.held_lost.held == {}
    # r3 goes just after the stall and does not come back: lost when the grace ends
    rt.inbound.on_liveliness("r3", False, rt._clock())
    wait(rt, fake, rn.STALL_GRACE / 2)
    assert rt.inbound.release_lost(rt._clock()) == [] and "r3" in rt.held_lost.held
    wait(rt, fake, rn.STALL_GRACE)
    rt.inbound.release_lost(rt._clock())
    assert rt.held_lost.held == {}
    assert rt.node.view.is_lost("r3")


def test_far_from_a_stall_a_lost_teammate_is_lost_at_once(driver):
    rt, fake = driver
    rt._clock()
    fake.t += rn.STALL_GRACE + 10  # no stall: the driver allowed itself this wait
    rt.awake.sleep_until = fake.t
    rt.inbound.on_liveliness("r2", False, rt._clock())
    assert rt.held_lost.held == {} and rt.node.view.is_lost("r2")


class FakePub:
    def __init__(self, matching: bool) -> None:
        self.sent: list[bytes] = []
        self._matching = matching

    def matching(self) -> bool:
        return self._matching

    def put(self, data: bytes) -> None:
        self.sent.append(data)


def test_an_outcome_waits_for_its_own_client_only_and_not_for_ever(driver):
    """An outcome for a client that is not reachable (its link lapsed, or it
    is gone) is held; outcomes for other clients are not held behind it; it
    goes when its client is back, or after OUTCOME_HOLD regardless."""
    rt, fake = driver
    rt.transport = MemoryBus().transport("r1")  # only outbox.pubs is used
    gone, here = FakePub(matching=False), FakePub(matching=True)
    rt.outbox.pubs = {"k/gone": gone, "k/here": here}
    rt.clients.send_outcome("k/gone", b"1")
    rt.clients.send_outcome("k/here", b"2")
    rt.clients.send_outcome("k/gone", b"3")
    assert here.sent == [b"2"] and gone.sent == []
    rt.clients.flush_outcomes()
    assert gone.sent == []
    gone._matching = True  # the client's link is back
    rt.clients.flush_outcomes()
    assert gone.sent == [b"1", b"3"] and rt.clients.held_outcomes == []
    gone._matching = False
    rt.clients.send_outcome("k/gone", b"4")
    fake.t += rn.OUTCOME_HOLD + 0.1
    rt.clients.flush_outcomes()
    assert gone.sent[-1] == b"4" and rt.clients.held_outcomes == []  # sent regardless, in the end


def test_a_stall_that_may_have_closed_links_is_told_to_the_core_once(driver):
    """A stall of half the Zenoh lease or more is told to the core as
    ``Stalled`` (it waits for teammates' links before counting their
    silence, ramps.core.relink); a shorter one is not. A teammate whose
    liveliness went and came back after the stall is back for the core."""
    rt, fake = driver
    lease = rt.s.lease_ms / 1000.0
    rt._clock()
    rt.awake.sleep_until = fake.t
    fake.t += lease * 0.3  # a short stall (busy robot): links stay up
    now = rt._clock()
    assert rt.awake.stalls == 1 and not rt.awake.links  # told to the core (silence counts from the wake), no relinking
    assert [a.what for a in rt._stall_told(now)] == [] and rt.node.origin.woke_at == now
    assert not rt.node.origin.relink.active(now)
    rt.awake.sleep_until = fake.t
    fake.t += lease * 2  # frozen past the lease: teammates' links closed
    now = rt._clock()
    notes = [a.what for a in rt._stall_told(now)]
    assert notes == ["relinking"] and rt.awake.pending == 0.0
    assert rt.node.origin.relink.waiting("r2", now)
    rt.inbound.on_liveliness("r2", False, now)  # held, see above
    wait(rt, fake, 0.2)
    acts = rt.inbound.on_liveliness("r2", True, rt._clock())
    assert [a.robot for a in acts if isinstance(a, Note) and a.what == "relinked"] == ["r2"]
    assert not rt.node.origin.relink.waiting("r2", rt._clock())
    assert rt.node.origin.relink.waiting("r3", rt._clock())


def test_a_request_asked_again_is_answered_again_and_never_run_twice(driver, monkeypatch):
    """A client asks about its pending requests again once its link to the
    node is back after a lapse (an outcome sent meanwhile may have gone
    nowhere, whatever Zenoh's matching said): a running request gets an
    update, an answered one its outcome again, one whose outcome is no longer
    kept an outcome saying so; none runs twice."""
    from ramps.core.events import Note
    from ramps.core.messages import ProgramOutcome, ProgramUpdate, SubmitProgram, decode
    from ramps.runtime import keys

    rt, fake = driver
    bus = MemoryBus()
    rt.transport = bus.transport("r1")
    app = bus.transport("app")
    heard: list[bytes] = []
    app.subscribe(keys.client(rt.team, "app"), heard.append)
    rt.incarnation = 7
    monkeypatch.setattr(node_clients, "OUTCOMES_KEPT_BYTES", 500)
    sub = [SubmitProgram(client="app", request_id=i, program="echo", args=encode_args(x=1))
           for i in (1, 2)]
    first = rt.clients.submit(sub[0], rt._clock())
    assert sum(isinstance(a, Note) and a.what == "placed" for a in first) == 1
    again = rt.clients.submit(sub[0], rt._clock())
    assert not any(isinstance(a, Note) and a.what == "placed" for a in again)
    [data] = heard
    assert isinstance(decode(data).msg, ProgramUpdate)
    [pid] = list(rt.clients.clients)
    rt.clients.tell(pid, ok=True, value=b"v" * 100, host="r1", attempts=1)

    def outcomes() -> list[bytes]:  # blocking puts on the client's key
        return [d for k, d, block in rt.transport.sent if block and k == keys.client(rt.team, "app")]

    assert len(outcomes()) == 1 and len(heard) == 2
    rt.clients.submit(sub[0], rt._clock())  # the outcome went nowhere: asked again
    assert outcomes()[1] == outcomes()[0] and decode(outcomes()[1]).msg.value == b"v" * 100
    rt.clients.submit(sub[1], rt._clock())
    [pid2] = list(rt.clients.clients)
    rt.clients.tell(pid2, ok=True, value=b"w" * 300, host="r1", attempts=1)  # over the bytes kept: 1 goes
    rt.clients.submit(sub[0], rt._clock())
    lost = decode(outcomes()[-1]).msg
    assert isinstance(lost, ProgramOutcome) and not lost.ok and "no longer keeps" in lost.error
    assert rt.clients.kept_bytes == len(outcomes()[2])  # only request 2's outcome is kept


def encode_args(**kw) -> bytes:
    import msgspec

    return msgspec.msgpack.encode(kw)


def test_periodic_reports_list_a_few_links_in_turn_and_a_client_keeps_them_all(driver):
    """A report's size does not grow with the team: each lists
    ``LINKS_PER_REPORT`` teammates' links, the next ones in the next report,
    and a client's status shows the newest of every one."""
    import msgspec

    from ramps.core.messages import encode
    from ramps.runtime.futures import TeamReports
    from ramps.runtime.node_reports import LINKS_PER_REPORT

    rt, fake = driver
    mates = [f"m{i:02d}" for i in range(2 * LINKS_PER_REPORT + 3)]
    for i, m in enumerate(mates):
        rt.node.host_speeds.factor[m] = 1.0 + i / 100
    reports = TeamReports()
    listed: list[list[str]] = []
    for k in range(3):
        links = rt.reports._learned()["links"]
        listed.append([link.robot for link in links])
        rep = msgspec.structs.replace(report("r1"), seq=k + 1, links=links)
        reports.keep("r1", encode("r1", rep), fake.t)
        reports.status("t", {"r1", *mates}, set(), fake.t)
    assert all(len(names) == LINKS_PER_REPORT for names in listed)
    assert set(listed[0]) | set(listed[1]) | set(listed[2]) == set(mates)  # every teammate within three reports
    row = next(r for r in reports.status("t", {"r1", *mates}, set(), fake.t).robots if r.robot == "r1")
    assert [link.robot for link in row.links] == mates
    assert row.links[5].speed_factor == pytest.approx(1.05)
    gone = next(r for r in reports.status("t", {"r1", *mates[1:]}, set(), fake.t).robots if r.robot == "r1")
    # m00 left the team (and was never reported)
    assert [link.robot for link in gone.links] == mates[1:]
