"""An origin that restarts loses nothing: its durable record (SQLite,
``ramps.runtime.store``) brings back every program its clients submitted,
hosts that still run them deliver to the new process, programs whose copy
is gone are placed again, and each client receives each outcome once.
The real driver and core over the in-memory transport
(``ramps.testing.memory``); the same on real processes:
tests/test_origin_restart_e2e.py."""

from __future__ import annotations

import sqlite3

import pytest

from ramps.core.config import RampsConfig
from ramps.core.durable import decode_record, encode_record, program_of, record_of
from ramps.core.events import Note, Send, Submit
from ramps.core.program import AutonomousProgram, ProgramState
from ramps.errors import ConfigError
from ramps.runtime.store import OriginStore
from ramps.testing.memory import MemoryTeam


def make_team(tmp_path, hold: float = 30.0) -> MemoryTeam:
    t = MemoryTeam({"r1": (1, 1.0), "r2": (2, 4.0), "r3": (2, 4.0)},
                   settings={"state_dir": str(tmp_path), "core": RampsConfig(origin_hold=hold)})
    t.run(3.0)
    return t


def ran(team: MemoryTeam, robot: str) -> list[str]:
    return [key[0] for key, _ in team.pools[robot].ran]


@pytest.mark.parametrize("down_for, hold", [(5.0, 30.0), (8.0, 3.0)], ids=["hosts-keep-them", "hosts-gave-up"])
def test_an_origin_killed_and_restarted_delivers_every_program_once(tmp_path, down_for, hold):
    team = make_team(tmp_path, hold)
    client = team.connect("r1")
    try:
        futs = [client.options(work=8.0).submit("echo", x=i) for i in range(6)]
        team.run(3.0, complete=False, until=lambda: sum(len(p.jobs) for p in team.pools.values()) == 6)
        where = {key[0]: robot for robot, pool in team.pools.items() for key in pool.jobs}
        assert len(where) == 6 and set(where.values()) & {"r2", "r3"}
        assert team.nodes["r1"].store.programs() == 6  # all written down before anything ran
        team.kill("r1")
        team.run(down_for, complete=False)
        if hold < down_for:  # the hosts stopped them: their copies are gone
            assert not team.pools["r2"].jobs and not team.pools["r3"].jobs
        else:
            assert all(team.pools[r].jobs for r in set(where.values()) - {"r1"})
        rt = team.add("r1", cores=1, speed=1.0, seed=7)  # the supervisor starts it again: a new incarnation
        assert rt.clients.restored == 6 and rt.incarnation != 1
        team.run(60.0, until=lambda: all(f.done() for f in futs))
        assert [f.result(0) for f in futs] == [{"x": i} for i in range(6)]
        runs = {pid: sum(ran(team, r).count(pid) for r in ("r1", "r2", "r3")) for pid in where}
        for pid, host in where.items():
            if host == "r1" or hold < down_for:  # its copy died: placed again, from the record
                assert runs[pid] == 2, (pid, host, runs)
            else:  # the host kept it running and delivered it to the new process: run once
                assert runs[pid] == 1, (pid, host, runs)
        team.run(5.0)
        assert rt.store.programs() == 0  # each replaced by its outcome
        assert all(f.attempts >= 1 for f in futs)
    finally:
        client.close()
        team.close()
    assert not list(tmp_path.rglob("*.sqlite"))  # a clean stop with nothing left leaves no file


def test_a_clean_stop_keeps_the_programs_for_the_next_start(tmp_path):
    team = make_team(tmp_path)
    client = team.connect("r1")
    try:
        futs = [client.options(work=8.0).submit("echo", x=i) for i in range(3)]
        team.run(3.0, complete=False, until=lambda: sum(len(p.jobs) for p in team.pools.values()) == 3)
        team.stop("r1")  # SIGTERM from a supervisor that restarts it: its clients are not told "shut down"
        team.run(1.0, complete=False)
        assert not any(f.done() for f in futs)
        team.add("r1", cores=1, speed=1.0, seed=9)
        team.run(30.0, until=lambda: all(f.done() for f in futs))
        assert [f.result(0) for f in futs] == [{"x": i} for i in range(3)]
    finally:
        client.close()
        team.close()


def test_a_record_of_another_robot_is_refused_and_a_corrupt_one_set_aside(tmp_path):
    OriginStore(tmp_path, team="t", robot="r1").close()
    other = tmp_path / "t" / "r2.sqlite"
    (tmp_path / "t" / "r1.sqlite").rename(other)
    with pytest.raises(ConfigError, match="record of robot 'r1' of team 't', not of robot 'r2'"):
        OriginStore(tmp_path, team="t", robot="r2")
    bad = tmp_path / "t" / "r3.sqlite"
    bad.write_bytes(b"not a database, a disk that lost a sector" * 100)
    store = OriginStore(tmp_path, team="t", robot="r3")  # no crash loop under a supervisor
    assert store.load().programs == {} and list((tmp_path / "t").glob("r3.sqlite.corrupt-*"))
    store.close()


def test_the_record_round_trips_and_skips_rows_it_cannot_read(tmp_path):
    ap = AutonomousProgram(Submit(program_id="r1#1-1", program="echo", args=b"\x81\xa1x\x01", work=2.0), 0.0)
    ap.attempt = ap.made = 2
    ap.host, ap.live, ap.failures = "r2", {1: "r3", 2: "r2"}, 1
    ap.checkpoint, ap.checkpoint_fraction = b"state", 0.4
    rec = decode_record(encode_record(record_of(ap)))
    back = program_of(rec, 100.0)
    assert (back.submit, back.attempt, back.host, back.live, back.made, back.checkpoint, back.checkpoint_fraction) \
        == (ap.submit, 2, "r2", {1: "r3", 2: "r2"}, 2, b"state", 0.4)
    store = OriginStore(tmp_path, team="t", robot="r1")
    store.save({"r1#1-1": ("app", 1, rec)}, [])
    store.save({}, [("r1#1-0", "app", 0, b"outcome")])
    with sqlite3.connect(store.path) as db:
        db.execute("INSERT INTO programs VALUES ('r1#1-2', 'app', 2, x'c1')")  # not a record
    found = store.load()
    assert list(found.programs) == ["r1#1-1"] and found.skipped == 1 and found.outcomes == {("app", 0): b"outcome"}
    store.close()


def test_restore_waits_for_the_host_then_places_again(tmp_path):
    """The core alone: a resumed program on a teammate is offered there
    again until its grace runs out; one that ran on the origin is placed at once."""
    from ramps.core.durable import RESTORE_GRACE

    team = MemoryTeam({"r1": (1, 1.0), "r2": (2, 4.0)})
    try:
        team.run(3.0)
        origin = team.nodes["r1"].node.origin
        away = AutonomousProgram(Submit(program_id="old-1", program="echo", work=1.0), 0.0)
        away.attempt = away.made = 1
        away.host, away.live = "r2", {1: "r2"}
        here = AutonomousProgram(Submit(program_id="old-2", program="echo", work=1.0), 0.0)
        here.attempt = here.made = 1
        here.host, here.live = "r1", {1: "r1"}
        now = team.nodes["r1"]._clock()
        out: list = []
        origin.restore([away, here], now, out)
        assert [n.what for n in out if isinstance(n, Note)] == ["restored", "restored"]
        [offer] = [a.msg for a in out if isinstance(a, Send)]  # the same attempt, offered to its host again
        assert (offer.program_id, offer.attempt, offer.host) == ("old-1", 1, "r2")
        assert away.state is ProgramState.OFFERED and away.deadline == now + RESTORE_GRACE
        assert here.state is ProgramState.BACKOFF and here.live == {}
        again: list = []
        origin.on_peer_alive("r2", now + 1.0, again)  # its liveliness heard: offered once more
        assert [a.msg.program_id for a in again if isinstance(a, Send)] == ["old-1"]
        team.nodes["r1"].outbound.apply(out + again)
        team.run(3.0)  # r2 takes it (it never had it) and runs it; the other is placed again
        assert away.state is not ProgramState.OFFERED and here.state is not ProgramState.BACKOFF
    finally:
        team.close()


@pytest.mark.parametrize("down", [5.0, 60.0])
def test_in_the_simulator_an_origin_with_a_record_resumes_after_a_crash(down):
    """The same core in the simulator: an origin that crashes and recovers
    with its record delivers every program once; without one (the paper's
    model) its programs are lost with it."""
    from ramps.sim.engine import simulate
    from ramps.sim.scenario import FaultSpec, ProgramSpec, RobotSpec, Scenario

    def run(record: bool):
        sc = Scenario(robots=[RobotSpec(name="r1", cores=2, record=record), RobotSpec(name="w{i}", count=3, cores=2)],
                      programs=[ProgramSpec(origin="r1", count=15, work=20.0)],
                      faults=[FaultSpec(at=3.0, robot="r1", kind="crash"),
                              FaultSpec(at=3.0 + down, robot="r1", kind="recover")])
        return simulate(sc, seed=1)

    kept = run(True)
    assert kept.completed == 15 and kept.lost == 0 and kept.duplicated == 0
    assert all(p.deliveries == 1 and p.ok for p in kept.programs)
    started = sum(st.accepted_total for st in kept.statistics if st.robot != "r1")  # runs begun on the teammates
    if down < RampsConfig().origin_hold:
        assert started <= 15  # their copies ran on through the crash: none began twice
    else:
        assert started > 15  # the hosts gave up on the absent origin: its programs began again, from the record
    lost = run(False)
    assert lost.completed < 15 and all(p.error == "origin crashed" for p in lost.programs if not p.ok)


def test_the_campaign_explains_a_resumed_attempt_written_off_only_when_the_crash_explains_it():
    """The testbed campaign's check (``_unexplained``): an attempt resumed
    after the origin's crash and written off later is explained when the
    origin never saw it accepted (the offer went down with it) or its host
    had a fault meanwhile; one accepted on a host without fault is not."""
    from ramps.sim.engine import TraceEntry
    from ramps.lab.campaign import _unexplained

    def trace(accepted: bool) -> list[TraceEntry]:
        t = [TraceEntry(10.0, "r1", "placed", "p", "r4", 1, "")]
        t += [TraceEntry(10.1, "r1", "accepted", "p", "r4", 1, "")] if accepted else []
        return t + [TraceEntry(15.0, "r1", "restored", "p", "r4", 1, ""),
                    TraceEntry(25.0, "r1", "failed", "p", "r4", 1, "connect_timeout")]

    assert _unexplained(trace(False), {}, "r1") == []
    assert _unexplained(trace(True), {"r4": [(12.0, 19.0)]}, "r1") == []  # r4 crashed while r1 was away
    assert len(_unexplained(trace(True), {}, "r1")) == 1
    assert len(_unexplained(trace(True), {"r1": [(11.0, 20.0)]}, "r1")) == 1  # the origin's own fault explains none


def test_the_record_keeps_the_newest_outcomes_up_to_its_bound(tmp_path, monkeypatch):
    import ramps.runtime.store as st

    monkeypatch.setattr(st, "OUTCOMES_MAX", 3)
    store = OriginStore(tmp_path, team="t", robot="r1")
    for i in range(5):
        store.save({}, [(f"p{i}", "app", i, b"o%d" % i)])
    assert sorted(store.load().outcomes) == [("app", 2), ("app", 3), ("app", 4)]
    store.close()
    again = OriginStore(tmp_path, team="t", robot="r1")  # counted again at start: still bounded
    again.save({}, [("p5", "app", 5, b"o5")])
    assert sorted(again.load().outcomes) == [("app", 3), ("app", 4), ("app", 5)]
    again.close()


def test_the_record_syncs_as_configured_and_refuses_other_words(tmp_path):
    from ramps.errors import ConfigError
    from ramps.runtime.settings import load_settings
    from ramps.runtime.store import OriginStore

    # SQLite's synchronous: 1 NORMAL (the default: survives the node's crash), 2 FULL (fsync each write)
    for sync, level in (("normal", 1), ("full", 2)):
        store = OriginStore(tmp_path / sync, team="t", robot="r1", sync=sync)
        assert store._db.execute("PRAGMA synchronous").fetchone()[0] == level
        assert store._db.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
        store.close()
    with pytest.raises(ConfigError, match="state_sync must be one of normal, full"):
        OriginStore(tmp_path / "x", team="t", robot="r1", sync="sometimes")
    assert load_settings(flags={"robot": "r1"}, environ={}).state_sync == "normal"
    assert load_settings(flags={"robot": "r1"}, environ={"RAMPS_STATE_SYNC": "full"}).state_sync == "full"
    with pytest.raises(ConfigError, match="state_sync must be 'normal' or 'full'"):
        load_settings(flags={"robot": "r1"}, environ={"RAMPS_STATE_SYNC": "always"})
