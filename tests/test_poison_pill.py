"""A program that kills its own worker is a poison pill: its origin stops
placing it after a small bound, and its error says how each attempt ended.

The origin's side (the pure core, through ``FakeTeam``): a worker that died
by itself (``worker_died``) on two robots, or three times on a lone one,
ends the program with every attempt's cause; a worker lost with its host
(the host shut down, crashed, went silent) is the ordinary failure path and
is placed again. The executor's side (real processes): a worker that dies
by itself is reported with its exit code or signal and the last lines of
its stderr, as the fork server saw them, and marked ``died``; a program's
``sys.exit`` is its own error, not a dead worker."""

from __future__ import annotations

import os
import threading
import time
from pathlib import Path

import msgspec
import pytest

from ramps.core.events import Deliver, PeerLost
from ramps.errors import ProgramFailed
from ramps.runtime.workers import WorkerPool
from ramps.testing import FakeTeam
from ramps.testing.memory import MemoryTeam

from corehelpers import busy_origin_team, submit

TESTS = str(Path(__file__).parent)
POISON = {n: f"poison_progs:{n}" for n in ("exits", "segfaults", "kills_itself", "quits", "fine")}


def _died(team: FakeTeam, robot: str, attempt: int, how: str = "exit code 3") -> None:
    team.finish(robot, "p", attempt, ok=False, retryable=True, worker_died=True,
                error=f"worker process died under the program: {how}")


def _placed(team: FakeTeam) -> list[tuple[int, str]]:
    return [(n.attempt, n.robot) for n in team.notes("placed")]


# =================================================================== the origin decides
def test_a_program_that_kills_its_worker_on_two_robots_is_not_placed_again():
    team = busy_origin_team()
    submit(team)
    team.deliver()
    _died(team, "a", 1, "exit code 3")
    assert not team.delivered("p")
    [(_, first), (_, second)] = _placed(team)
    assert first == "a" and second != "a"  # placed again at once, elsewhere
    _died(team, second, 2, "killed by signal 11 (SIGSEGV)")
    [d] = team.delivered("p")
    assert not d.ok and d.error_kind == "program" and d.attempts == 2 and d.host == second
    assert "killed its own worker on 2 robots" in d.error
    assert "attempt 1 on a: worker process died under the program: exit code 3" in d.error
    assert f"attempt 2 on {second}: worker process died under the program: killed by signal 11 (SIGSEGV)" in d.error
    assert len(_placed(team)) == 2  # and nothing placed after it


def test_on_a_lone_robot_it_ends_after_three_attempts():
    team = FakeTeam({"o": (2, 1.0)})
    team.publish()
    submit(team)
    team.deliver()
    for attempt in (1, 2):
        _died(team, "o", attempt)
        assert not team.delivered("p")
    _died(team, "o", 3)
    [d] = team.delivered("p")
    assert not d.ok and d.attempts == 3 and "killed its own worker 3 times on o" in d.error
    assert _placed(team) == [(1, "o"), (2, "o"), (3, "o")]


def test_workers_lost_with_their_host_are_no_poison_pill():
    """The failure and restart path the paper is about: a host that shut
    down (its executor hands programs back: retryable, not ``worker_died``)
    or crashed is retried, however many robots it happens on."""
    team = busy_origin_team()
    submit(team)
    team.deliver()
    team.finish("a", "p", 1, ok=False, retryable=True, error="a is shutting down")
    [_, (_, second)] = _placed(team)
    team.finish(second, "p", 2, ok=False, retryable=True, error=f"{second} is shutting down")
    assert not team.delivered("p")
    [*_, (attempt, third)] = _placed(team)
    assert attempt == 3
    # one worker that died by itself, then a host that crashed: still placed again
    _died(team, third, 3)
    [*_, (attempt, fourth)] = _placed(team)
    assert attempt == 4
    team.handle("o", PeerLost(robot=fourth))
    team.deliver()
    assert not team.delivered("p")
    team.advance(team.now + 5.0)
    [*_, (attempt, fifth)] = _placed(team)
    assert attempt == 5
    team.finish(fifth, "p", 5, ok=True, value=b"ok")
    assert team.delivered("p") == [Deliver(program_id="p", ok=True, value=b"ok", host=fifth, attempts=5)]


def _pool_run(jobs: list[tuple[str, dict]]) -> dict:
    done: dict = {}
    all_done = threading.Event()

    def finished(key, ok, value, error, retryable, cpu_s=None, died=False):
        done[key[0]] = (ok, error, retryable, died)
        if len(done) == len(jobs):
            all_done.set()

    env = dict(os.environ, PYTHONPATH=os.pathsep.join([TESTS, os.environ.get("PYTHONPATH", "")]))
    pool = WorkerPool(1, POISON, finished, env=env)
    pool.start()
    try:
        for name, kw in jobs:
            pool.run((name, 1), name, msgspec.msgpack.encode(kw))
        assert all_done.wait(30), done
    finally:
        pool.stop()
    return done


@pytest.mark.slow
def test_a_worker_that_dies_by_itself_is_reported_with_how_it_ended():
    done = _pool_run([("exits", {"code": 3, "say": "opening the map\nmap file is corrupt"}),
                      ("segfaults", {}), ("kills_itself", {}), ("quits", {"code": 4}), ("fine", {"x": 5})])
    ok, error, retryable, died = done["exits"]
    assert (ok, retryable, died) == (False, True, True)
    assert "exit code 3" in error and "map file is corrupt" in error, error
    ok, error, retryable, died = done["segfaults"]
    assert (retryable, died) == (True, True)
    assert "signal 11 (SIGSEGV)" in error and "in segfaults" in error, error  # faulthandler's traceback
    assert "forkserver.py" not in error and "Extension modules" not in error  # ramps's frames, C modules: out
    assert done["kills_itself"][2:] == (True, True) and "signal 9 (SIGKILL)" in done["kills_itself"][1]
    # sys.exit is the program's own error: not retried, its worker lives on
    assert done["quits"] == (False, "program 'quits' called sys.exit(4)", False, False)
    assert done["fine"][0] is True


# =================================================================== both, end to end
class _PoolTeam(MemoryTeam):
    """A ``MemoryTeam`` whose nodes run their programs in real worker pools
    (fork server, worker processes), so a program can kill its worker."""

    def make_pool(self, *a, **kw):
        env = dict(os.environ, PYTHONPATH=os.pathsep.join([TESTS, os.environ.get("PYTHONPATH", "")]))
        return WorkerPool(*a, env=env, **kw)


@pytest.mark.slow
def test_a_program_that_exits_its_worker_fails_at_the_caller_with_each_attempts_cause():
    team = _PoolTeam({"r1": (1, 1.0), "r2": (1, 1.0)}, programs=["poison_progs:exits"])
    try:
        team.run(3.0, complete=False)  # load reports exchanged
        app = team.connect("r1")
        fut = app.submit("exits", code=3, say="map file is corrupt")
        end = time.monotonic() + 30
        while not fut.done() and time.monotonic() < end:
            team.run(0.05, complete=False)
            time.sleep(0.005)
        with pytest.raises(ProgramFailed) as ei:
            fut.result(0)
        text = str(ei.value)
        assert "killed its own worker on 2 robots" in text, text
        assert text.count("exit code 3") == 2 and text.count("map file is corrupt") == 2, text
        assert "attempt 1 on r" in text and "attempt 2 on r" in text
        assert ei.value.attempts == 2
        app.close()
    finally:
        team.close()
