"""End to end: a node that stays right when its robot stalls or half-dies
(issue 14, runtime side). Real ``ramps node`` processes on loopback
(``runtime_team.LocalTeam``), real workers, real signals.

- A node frozen (SIGSTOP of the node process only, its workers run on) for
  5 s restarts none of the programs it is origin of: its trace shows no
  heartbeat timeout, no back-off and no second attempt, and each program
  completes once.
- A node killed alone (SIGKILL of the node process, not its group) takes its
  worker processes with it at once: no work goes on that nobody will ever
  collect.
"""

from __future__ import annotations

import json
import os
import signal
import time
from pathlib import Path

import psutil
import pytest
from runtime_team import LocalTeam, assert_no_leftovers, wait_for

pytestmark = pytest.mark.slow

RESULT_TIMEOUT = 60.0


@pytest.fixture(scope="module", autouse=True)
def no_leftover_processes():
    yield
    assert_no_leftovers()


def trace_lines(path: Path) -> list[dict]:
    if not path.exists():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def _stall(t: LocalTeam, robot: str, seconds: float) -> None:
    pid = t.nodes[robot].pid
    os.kill(pid, signal.SIGSTOP)
    try:
        time.sleep(seconds)
    finally:
        os.kill(pid, signal.SIGCONT)


BAD = ("heartbeat_timeout", "backoff", "host_failed")


def _two_sleepy(t: LocalTeam, trace: Path, *, seconds: float, tag: str, start_within: float) -> tuple:
    """r1 (tracing) and r2 up; r1's application (returned: keep it) submits
    two programs that sleep ``seconds``, one on each robot (round robin),
    and sees both start."""
    t.start_node("r1", extra_env={"RAMPS_TRACE": str(trace)}, wait=False)
    t.start_node("r2", wait=False)
    t.wait_visible(["r1", "r2"])
    team = t.client("r1")
    futs = [team.options(policy="round_robin").submit("sleepy", seconds=seconds, tag=f"{tag}{i}") for i in range(2)]
    wait_for(lambda: all((t.marks / f"{tag}{i}").exists() for i in range(2)), start_within, "both programs to start")
    return team, futs


def _assert_clean_trace(trace: list[dict], pid: str) -> None:
    mine = [e for e in trace if e["program_id"] == pid]
    bad = [e for e in mine if any(b in e["what"] or b in e["detail"] for b in BAD) or e["attempt"] > 1]
    assert not bad, "the stalled origin wrote off a healthy program:\n" + "\n".join(map(str, mine))
    delivered = [e for e in mine if e["what"] == "delivered"]
    assert len(delivered) == 1, mine


def test_stalled_origin_restarts_none_of_its_programs(tmp_path):
    """SIGSTOP the origin's node 2 s into two 8 s programs, SIGCONT 5 s
    later. One program runs on the stalled robot itself (the node's own
    heartbeats), one on a teammate (its heartbeats and result queue up, or
    Zenoh drops them, while the origin is frozen). Neither may be written
    off: no heartbeat timeout, no back-off, no attempt 2, one delivery each."""
    trace = tmp_path / "r1.trace"
    t = LocalTeam(2, tmp_path, cores=2)
    try:
        team, futs = _two_sleepy(t, trace, seconds=8.0, tag="p", start_within=20)
        hosts = sorted((t.marks / f"p{i}").read_text().split()[0] for i in range(2))
        assert hosts == ["r1", "r2"], hosts
        time.sleep(2.0)
        _stall(t, "r1", 5.0)
        res = [f.result(timeout=RESULT_TIMEOUT) for f in futs]
        assert sorted(r["tag"] for r in res) == ["p0", "p1"]
        time.sleep(0.5)
        entries = trace_lines(trace)
        pids = sorted({e["program_id"] for e in entries if e["what"] == "placed"})
        assert len(pids) == 2, entries
        stalls = [e for e in entries if e["what"] == "stalled"]
        assert stalls and float(stalls[0]["detail"]) > 3.0, stalls  # the node saw its own stall
        for pid in pids:
            _assert_clean_trace(entries, pid)
    finally:
        t.close()


def test_node_killed_alone_takes_its_workers_with_it(tmp_path):
    """SIGKILL of the node process only (not its process group): the fork
    server and the workers running its programs are gone from the process
    table within 1 s, so no work goes on that nobody will collect."""
    with LocalTeam(2, tmp_path, cores=2) as t:
        team = t.client("r2")
        futs = [team.options(policy="round_robin").submit("sleepy", seconds=30.0, tag=f"k{i}") for i in range(4)]
        wait_for(lambda: sum(1 for i in range(4) if (t.marks / f"k{i}").exists()) == 4, 30, "programs to start")
        on_r1 = [int(m.read_text().split()[1]) for m in t.marks.iterdir()
                 if m.suffix != ".tmp" and m.read_text().split()[0] == "r1"]
        assert on_r1, "round robin placed nothing on r1"
        node = psutil.Process(t.nodes["r1"].pid)
        doomed = [psutil.Process(p) for p in on_r1] + [c for c in node.children(recursive=True)]
        os.kill(t.nodes["r1"].pid, signal.SIGKILL)  # the node alone: its workers are not signalled
        t.nodes["r1"].proc.wait(10)

        def gone(p: psutil.Process) -> bool:
            try:
                return p.status() == psutil.STATUS_ZOMBIE
            except psutil.NoSuchProcess:
                return True

        deadline = time.monotonic() + 1.0
        while time.monotonic() < deadline and not all(gone(p) for p in doomed):
            time.sleep(0.02)
        alive = [p.pid for p in doomed if not gone(p)]
        assert not alive, f"processes of the killed node r1 still running: {alive}"
        for f in futs:
            f.cancel()


def test_what_ends_or_is_submitted_during_a_stall_reaches_its_place(tmp_path):
    """The application's node r1 is frozen past its lease, so Zenoh closes
    its links. A program that ended meanwhile is delivered the moment r1
    wakes, before the application's link is back: its outcome used to be
    published into the void. Programs submitted meanwhile used to go nowhere
    too: the application waited for ever. Now r1 holds the outcome until the
    application's link is back, and the client sends a submission again
    until r1 acknowledges it (r1 runs it once). The hold alone was not
    enough: in a team, Zenoh may report the application's subscriber as
    matched (through r2) while its link to r1 is down, and under load the
    outcome once went nowhere; so the client also asks about every pending
    program again once its link to r1 is back, and r1 answers again (an
    update, or the outcome it keeps)."""
    trace = tmp_path / "r1.trace"
    t = LocalTeam(2, tmp_path, cores=2)
    try:
        t.start_node("r1", extra_env={"RAMPS_TRACE": str(trace)}, wait=False)
        t.start_node("r2", wait=False)
        t.wait_visible(["r1", "r2"])
        team = t.client("r1")
        ends = team.options(local_only=True).submit("sleepy", seconds=1.5, tag="s")
        wait_for(lambda: (t.marks / "s").exists(), 60, "the program to start")
        pid = t.nodes["r1"].pid
        os.kill(pid, signal.SIGSTOP)
        try:
            time.sleep(0.1)  # these two reach r1's socket before its links lapse; r1 places them on waking
            later = [team.options(policy="round_robin").submit("where", x=i) for i in range(2)]
            time.sleep(2.4)  # the program ends 1.5 s in; the links lapse (lease 1 s)
            later.append(team.submit("where", x=2))  # the client holds this one
            time.sleep(1.5)
        finally:
            os.kill(pid, signal.SIGCONT)
        woke = time.monotonic()
        r = ends.result(timeout=RESULT_TIMEOUT)
        print(f"outcome reached the client {time.monotonic() - woke:.2f} s after the node woke")
        assert r["tag"] == "s" and r["robot"] == "r1"
        res = [f.result(timeout=RESULT_TIMEOUT) for f in later]
        # (where they ran is not asserted: an offer r1 sends to r2 the moment it wakes may be lost
        # while their link is rebuilt, and the program then runs elsewhere after a connect timeout)
        assert sorted(x["x"] for x in res) == [0, 1, 2], res
        time.sleep(0.3)
        placed = [e for e in trace_lines(trace) if e["what"] == "placed" and e["attempt"] == 1]
        assert len(placed) == 4, placed  # each request placed once, resends or not
    finally:
        t.close()


def test_a_program_whose_origin_crashed_and_came_back_completes_once(tmp_path):
    """The application's node r1 is killed (with its workers) while its two
    programs run, one on r1 and one on r2, and restarted 2 s later (within
    the client's grace) with its durable record: the copy on r2 runs on and
    delivers to the new r1; the one on r1 died with it and runs again; each
    completes once for the application."""
    trace = tmp_path / "r1.trace"
    t = LocalTeam(2, tmp_path, cores=2)
    try:
        team, futs = _two_sleepy(t, trace, seconds=3.0, tag="c", start_within=60)
        was = {f"c{i}": (t.marks / f"c{i}").read_text().split()[0] for i in range(2)}  # robot, pid
        assert sorted(was.values()) == ["r1", "r2"]
        for i in range(2):
            (t.marks / f"c{i}").unlink()
        t.kill_node("r1")
        time.sleep(2.0)
        t.start_node("r1", extra_env={"RAMPS_TRACE": str(trace)}, extra_args=["--connect", t.nodes["r2"].endpoint],
                     wait=False)
        res = [f.result(timeout=RESULT_TIMEOUT) for f in futs]
        assert sorted(r["tag"] for r in res) == ["c0", "c1"]
        again = sorted(tag for tag in was if (t.marks / tag).exists())
        assert again == [tag for tag, robot in was.items() if robot == "r1"]  # only r1's copy ran again
        entries = trace_lines(trace)
        delivered = [e for e in entries if e["what"] == "delivered"]
        assert len(delivered) == 2 and len({e["program_id"] for e in delivered}) == 2, delivered
    finally:
        t.close()
