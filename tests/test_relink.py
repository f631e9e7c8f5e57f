"""After an origin's own stall, a host's silence counts only once its link is
back (``ramps.core.relink``; issue 14). Pure core, through FakeTeam: the
origin ``o`` is swamped, so its programs run on ``a`` (fastest) or ``b``.

A stall shows in the core as a ``Stalled`` event at the wake (the driver
takes the stalled time out of the core's clock); the link to ``a`` being
rebuilt is ``a`` in ``team.cut`` (nothing from or to it arrives)."""

from __future__ import annotations

import pytest
from corehelpers import CFG, busy_origin_team, submit

from ramps.core.events import Note, PeerAlive, Received
from ramps.core.messages import Heartbeat, OffloadRequest
from ramps.core.program import ProgramState
from ramps.core.relink import RELINK_SETTLE, RELINK_TIMEOUT, Relink, Stalled

BAD = ("failed", "suspected", "backoff")


def running_on_a():
    team = busy_origin_team()
    submit(team)
    team.deliver()
    team.advance(3.0)  # heartbeats flow
    assert team.program("p").state is ProgramState.RUNNING and team.program("p").host == "a"
    return team


def bad_notes(team):
    return [n for n in team.actions(Note, "o") if n.what in BAD]


def test_a_host_whose_link_comes_back_after_the_origins_stall_is_not_written_off() -> None:
    # seed 26000008 of the stressed campaign: the origin woke from a 1.75 s
    # stall, a host's link came back 1.8 s later, and the origin's heartbeat
    # timeout (2 s, counted from the last heartbeat before the stall) wrote
    # the host off: 2 programs restarted for nothing
    team = running_on_a()
    stalled_at = team.now
    team.cut.add("a")  # the host's lease on o ran out during the stall: its link is being rebuilt
    team.handle("o", Stalled(seconds=1.75))
    team.advance(stalled_at + CFG.heartbeat_timeout + 0.5)  # longer than a heartbeat timeout
    assert not bad_notes(team), bad_notes(team)
    team.cut.clear()  # the link is back
    team.handle("o", PeerAlive(robot="a"))
    assert "a" in [n.robot for n in team.notes("relinked")]
    team.advance(team.now + 5.0)
    assert not bad_notes(team), bad_notes(team)
    ap = team.program("p")
    assert ap.state is ProgramState.RUNNING and ap.attempt == 1


def test_silence_counts_from_the_moment_the_link_is_back() -> None:
    # the host is heard again (PeerAlive) but then falls silent for good: it
    # is written off one heartbeat timeout after its link came back
    team = running_on_a()
    team.cut.add("a")
    team.handle("o", Stalled(seconds=2.0))
    team.advance(team.now + 1.0)
    team.handle("o", PeerAlive(robot="a"))
    back = team.now
    team.advance(back + CFG.heartbeat_timeout - 0.1)
    assert not bad_notes(team)
    team.advance(back + CFG.heartbeat_timeout + 0.1)
    assert [n.what for n in bad_notes(team)][:1] in (["failed"], ["suspected"])


def test_a_host_never_heard_after_the_stall_is_written_off_when_the_wait_ends() -> None:
    # a host that really died during the stall is not waited for beyond
    # the relink timeout
    team = running_on_a()
    team.cut.add("a")
    team.handle("o", Stalled(seconds=2.0))
    woke = team.now
    team.advance(woke + RELINK_TIMEOUT - 0.05)
    assert not bad_notes(team)
    team.advance(woke + RELINK_TIMEOUT + 0.05)
    failed = [n for n in team.actions(Note, "o") if n.what in ("failed", "suspected")]
    assert failed and failed[0].robot == "a"
    when = next(t for t, r, a in team.log if r == "o" and a is failed[0])
    assert when == pytest.approx(woke + RELINK_TIMEOUT)


def test_no_offer_goes_to_a_host_whose_link_is_not_back() -> None:
    # seed 24000001: the origin offered a program the moment it woke, to a
    # host whose link was being rebuilt; the offer went nowhere and timed out
    team = busy_origin_team()
    team.advance(1.0)
    team.handle("o", Stalled(seconds=1.6))
    # while every teammate relinks, the policy chooses among all: the swamped
    # origin does not keep everything (a's the fastest)
    submit(team, pid="q0")
    assert [r.host for r in team.sent(OffloadRequest)] == ["a"]
    team.handle("o", PeerAlive(robot="b"))  # b's link is back, a's is not
    submit(team, pid="q")
    assert [r.host for r in team.sent(OffloadRequest)] == ["a", "b"]
    # a message from a read right after the wake was sent before its link closed: proves nothing
    hb = Heartbeat(host="a", incarnation=0, programs=[])
    team.handle("o", Received(sender="a", msg=hb))
    submit(team, pid="q2")
    assert [r.host for r in team.sent(OffloadRequest)][-1] == "b"
    team.advance(team.now + RELINK_SETTLE)
    team.handle("o", Received(sender="a", msg=hb))  # later: a's link is back
    submit(team, pid="q3")
    assert [r.host for r in team.sent(OffloadRequest)][-1] == "a"


def test_an_offer_made_before_the_stall_waits_for_the_hosts_link() -> None:
    team = busy_origin_team()
    team.advance(1.0)
    team.cut.add("a")  # the offer is in flight when o stalls; a's link goes
    submit(team)
    team.deliver()
    team.handle("o", Stalled(seconds=2.0))
    team.advance(team.now + CFG.connect_timeout + 0.5)
    assert not bad_notes(team)
    team.cut.clear()
    team.handle("o", PeerAlive(robot="a"))  # the connect timeout counts from here
    team.advance(team.now + CFG.connect_timeout - 0.1)
    assert not bad_notes(team)
    team.advance(team.now + 0.2)
    assert bad_notes(team)  # the offer was lost: written off a connect timeout after the link came back


def test_relink_bookkeeping() -> None:
    r = Relink("o", timeout=3.0, settle=0.25)
    assert not r.waiting("a", 0.0) and r.excluded(["a", "o"], 0.0) == frozenset()
    r.stalled(10.0)
    assert r.waiting("a", 10.0) and not r.waiting("o", 10.0) and not r.waiting(None, 10.0)
    assert r.excluded(["a", "b", "c", "o"], 10.1) == frozenset()  # every teammate: choose among all
    assert r.heard("c", 10.1, certain=True)
    assert r.excluded(["a", "b", "c", "o"], 10.1) == {"a", "b"}
    assert not r.heard("a", 10.1)  # within the settle time
    assert r.heard("b", 10.1, certain=True) and not r.heard("b", 10.2, certain=True)
    assert r.heard("a", 10.3) and r.excluded(["a", "b"], 10.3) == frozenset()
    assert not r.waiting("d", 13.0) and r.relinked == 3 and r.stalls == 1
    with pytest.raises(ValueError):
        Relink("o", timeout=-1.0)
