"""End to end: executables as programs, and progress, on a real three-robot team.

Each robot's node registers the executables written below into the test's
temporary directory (``--command NAME=PATH``; one more, with a 1 s time
limit, from a ``[commands.NAME]`` table of a config file), and a Python
program that calls ``ramps.progress``. Clients submit them as they would any
program: only the name and JSON arguments travel.

Checked: a result comes back from stdout; a failing executable's exit code
and stderr tail reach the caller; the time limit kills it; a withdrawn one
(cancelled future) leaves no process of its group behind, nor does one whose
robot is killed under it (it is re-placed and finishes elsewhere); progress
from a Python program and from ``RAMPS_PROGRESS`` stderr lines reaches the
caller's future with the host and state.
"""

from __future__ import annotations

import json
import os
import sys
import time
from pathlib import Path

import psutil
import pytest
from runtime_team import LocalTeam, assert_no_leftovers

from ramps.errors import ProgramFailed, ProgramLost

pytestmark = pytest.mark.slow

RESULT_TIMEOUT = 60.0

SOLVE = f"""#!{sys.executable}
# reads its arguments (JSON) on stdin, reports progress on stderr, prints a JSON result
import json, os, sys, time
args = json.load(sys.stdin)
steps = int(args.get("steps", 3))
for i in range(steps):
    time.sleep(float(args.get("dt", 0.2)))
    print(f"RAMPS_PROGRESS {{(i + 1) / steps:.2f}} step {{i + 1}}", file=sys.stderr, flush=True)
print("some ordinary log line", file=sys.stderr)
json.dump({{"robot": os.environ.get("RAMPS_ROBOT"), "program": os.environ.get("RAMPS_PROGRAM"),
           "sum": sum(args.get("xs", []))}}, sys.stdout)
"""

FAILING = """#!/bin/sh
echo "loading map..." >&2
echo "error: no map named $(cat)" >&2
exit 3
"""

# a shell that starts a grandchild and records both pids, then waits forever
HANG = r"""#!/bin/sh
tag=$(sed 's/.*"tag": *"\([a-z0-9]*\)".*/\1/')
sleep 300 &
echo "$$ $! $RAMPS_ROBOT" > "$RAMPS_E2E_MARKS/$tag.tmp"
mv "$RAMPS_E2E_MARKS/$tag.tmp" "$RAMPS_E2E_MARKS/$tag"
wait
"""

# counts to n, checkpointing each step; resumes from RAMPS_RESUME; its marks
# say its pid, the step it reached and where it started
CKPT = f"""#!{sys.executable}
import json, os, sys, time
args = json.load(sys.stdin)
path = os.environ.get("RAMPS_RESUME")
start = json.load(open(path))["i"] if path else 0
marks = os.path.join(os.environ["RAMPS_E2E_MARKS"], args["tag"])
for i in range(start, args["n"]):
    time.sleep(args["dt"])
    print(f"RAMPS_PROGRESS {{(i + 1) / args['n']:.3f}}", file=sys.stderr, flush=True)
    print("RAMPS_CHECKPOINT " + json.dumps({{"i": i + 1}}), file=sys.stderr, flush=True)
    with open(marks + ".tmp", "w") as f:
        f.write(f"{{os.getpid()}} {{i + 1}} {{start}}")
    os.replace(marks + ".tmp", marks)
json.dump({{"start": start, "robot": os.environ.get("RAMPS_ROBOT")}}, sys.stdout)
"""
NOT_JSON = """#!/bin/sh
echo "done!"
"""


def _write(tmp: Path, name: str, text: str) -> Path:
    p = tmp / "bin" / name
    p.parent.mkdir(exist_ok=True)
    p.write_text(text)
    p.chmod(0o755)
    return p


class CommandTeam(LocalTeam):
    """A LocalTeam whose every node registers the executables and the stepper."""

    def __init__(self, n: int, tmp: Path, **kw) -> None:
        super().__init__(n, tmp, **kw)
        cfg = tmp / "commands.toml"
        cfg.write_text(f'[commands.slow]\npath = "{_write(tmp, "hang-slow", HANG)}"\ntimeout = 1.0\n')
        self.node_args = ["--config", str(cfg), "--program", "e2e_progress_progs:stepper"]
        for name, text in (("solve", SOLVE), ("failing", FAILING), ("hang", HANG), ("notjson", NOT_JSON),
                           ("ckpt", CKPT)):
            self.node_args += ["--command", f"{name}={_write(tmp, name, text)}"]

    def start_node(self, name, cores=None, extra_env=None, *, wait=True, extra_args=None):
        return super().start_node(name, cores, extra_env, wait=wait, extra_args=self.node_args + (extra_args or []))


@pytest.fixture(scope="module", autouse=True)
def no_leftover_processes():
    yield
    assert_no_leftovers()


@pytest.fixture(scope="module")
def team(tmp_path_factory):
    with CommandTeam(3, tmp_path_factory.mktemp("cmdteam"), cores=1) as t:
        yield t


@pytest.fixture(scope="module")
def client(team):
    return team.client("r1")


def _marks(t: LocalTeam, tag: str, timeout: float = 30.0) -> tuple[int, int, str]:
    path = t.marks / tag
    deadline = time.monotonic() + timeout
    while not path.exists():
        if time.monotonic() > deadline:
            raise AssertionError(f"the executable tagged {tag} never started\n{t.logs()}")
        time.sleep(0.05)
    shell, child, robot = path.read_text().split()
    return int(shell), int(child), robot


def _gone(pids: list[int], timeout: float = 15.0) -> list[int]:
    """Those of ``pids`` still alive (not zombies) after waiting up to ``timeout``."""
    deadline = time.monotonic() + timeout
    while True:
        alive = []
        for pid in pids:
            try:
                if psutil.Process(pid).status() != psutil.STATUS_ZOMBIE:
                    alive.append(pid)
            except psutil.NoSuchProcess:
                pass
        if not alive or time.monotonic() > deadline:
            return alive
        time.sleep(0.1)


def test_executable_result_comes_from_its_json_stdout(team, client):
    futs = [client.submit("solve", xs=[i, 2, 3], steps=1, dt=0.0) for i in range(6)]
    got = [f.result(RESULT_TIMEOUT) for f in futs]
    assert [g["sum"] for g in got] == [i + 5 for i in range(6)]
    assert all(g["program"] == "solve" for g in got)
    assert {g["robot"] for g in got} <= {"r1", "r2", "r3"}
    assert all(f.host == g["robot"] and f.state == "done" for f, g in zip(futs, got))


def test_failing_executable_returns_exit_code_and_stderr(team, client):
    fut = client.submit("failing", map="dock7")
    with pytest.raises(ProgramFailed) as err:
        fut.result(RESULT_TIMEOUT)
    text = str(err.value)
    assert "exited with code 3" in text
    assert 'error: no map named {"map": "dock7"}' in text  # its arguments came as JSON on stdin
    assert "loading map..." in text
    assert fut.state == "failed"


def test_executable_whose_stdout_is_not_json_is_a_clear_error(team, client):
    with pytest.raises(ProgramFailed, match="stdout is not JSON.*done!"):
        client.submit("notjson").result(RESULT_TIMEOUT)


def test_time_limit_kills_the_whole_group(team, client):
    fut = client.submit("slow", tag="slowone")
    shell, child, _ = _marks(team, "slowone")
    with pytest.raises(ProgramFailed, match="time limit of 1 s"):
        fut.result(RESULT_TIMEOUT)
    assert _gone([shell, child]) == []


def test_withdrawn_executable_leaves_no_process(team, client):
    fut = client.submit("hang", tag="cancelme")
    shell, child, robot = _marks(team, "cancelme")
    assert psutil.pid_exists(shell) and psutil.pid_exists(child)
    # the executable runs in its own process group, not the worker's
    assert os.getpgid(shell) == shell and os.getpgid(child) == shell
    assert fut.cancel()
    assert _gone([shell, child]) == [], f"the withdrawn program's processes survived on {robot}"


def test_progress_of_a_python_program_reaches_the_future(team, client):
    fut = client.submit("stepper", steps=6, dt=0.4)
    seen = []
    fut.add_update_callback(lambda f: seen.append((f.state, f.host, f.progress)))
    assert fut.result(RESULT_TIMEOUT)["steps"] == 6
    fractions = [p for _, _, p in seen if p is not None]
    assert fractions, f"no progress seen: {seen}"
    assert fractions == sorted(fractions) and 0 < fractions[0] <= 1
    assert any(s == "running" for s, _, _ in seen), seen
    assert all(h == fut.host for s, h, _ in seen if s == "running"), (seen, fut.host)


def test_progress_lines_of_an_executable_reach_the_future(team, client):
    fut = client.submit("solve", xs=[1], steps=5, dt=0.4)
    seen = []
    fut.add_update_callback(lambda f: seen.append((f.progress, f.progress_detail)))
    assert fut.result(RESULT_TIMEOUT)["sum"] == 1
    got = [p for p in seen if p[0] is not None]
    assert got and all(d.startswith("step ") for _, d in got), seen
    assert fut.progress is not None and fut.progress >= got[0][0]


def test_ramps_status_shows_running_programs_and_their_progress(team, client):
    fut = client.submit("stepper", steps=40, dt=0.3)
    try:
        deadline = time.monotonic() + RESULT_TIMEOUT
        while fut.progress is None and time.monotonic() < deadline:
            time.sleep(0.1)
        assert fut.progress is not None, "no progress before the status check"
        eps = [a for ep in team.endpoints() for a in ("--connect", ep)]
        st = team.cli("status", "--team", team.team, *eps, "--no-multicast", "--json", "--wait", "1.5")
        assert st.returncode == 0, st.stderr
        rows = {r["robot"]: r for r in json.loads(st.stdout)["robots"]}
        listed = [(robot, p) for robot, r in rows.items() for p in r["running"]]
        ours = [(robot, p) for robot, p in listed if p[0] == "stepper"]
        assert ours, listed
        robot, (program, origin, progress) = ours[0]
        assert robot == fut.host and origin == "r1" and progress is not None and 0 < progress <= 1, ours
        table = team.cli("status", "--team", team.team, *eps, "--no-multicast", "--wait", "1.2").stdout
        assert "running programs" in table and "stepper" in table and "%" in table, table
    finally:
        fut.cancel()


def test_ramps_submit_progress_prints_host_state_and_progress(team):
    eps = [a for ep in team.endpoints() for a in ("--connect", ep)]
    run = team.cli("submit", "stepper", "--arg", "steps=4", "--arg", "dt=0.3", "--team", team.team, "--robot", "r1",
                   *eps, "--no-multicast", "--progress")
    assert run.returncode == 0, run.stderr
    assert "stepper: running on r" in run.stderr and "% step " in run.stderr, run.stderr


def test_an_executable_that_checkpoints_resumes_after_its_worker_dies(team, client):
    """RAMPS_CHECKPOINT lines reach the origin; when the worker under the
    executable is killed, the program runs again with RAMPS_RESUME naming
    its latest state, and the caller sees where it resumed from."""
    t, c = team, client
    fut = c.submit("ckpt", tag="ck1", n=40, dt=0.1)
    deadline = time.monotonic() + 60
    while True:  # until it has checkpointed a few steps
        text = (t.marks / "ck1").read_text() if (t.marks / "ck1").exists() else ""
        if text and int(text.split()[1]) >= 8:
            break
        assert time.monotonic() < deadline, f"the executable never got going\n{t.logs()}"
        time.sleep(0.05)
    time.sleep(0.3)  # the latest checkpoint reaches the origin with the next heartbeat at most
    pid = int(text.split()[0])
    worker = psutil.Process(pid).parent()
    assert worker is not None and "ramps" in " ".join(worker.cmdline())
    worker.kill()
    result = fut.result(RESULT_TIMEOUT)
    assert result["start"] >= 5, result  # resumed from a checkpoint, not from step 0
    assert fut.resumed_from is not None and 0 < fut.resumed_from <= 1
    assert _gone([pid]) == []


def test_killed_robot_kills_its_executables_and_the_program_moves(team, client):
    """Last in this module: it kills a robot of the shared team."""
    t, c = team, client
    futs = {tag: c.options(policy="round_robin").submit("hang", tag=tag) for tag in ("k1", "k2", "k3")}
    marks = {tag: _marks(t, tag) for tag in futs}  # round robin from r1: one on each robot
    victim = next(robot for _, _, robot in marks.values() if robot != "r1")
    doomed = [pid for shell, child, robot in marks.values() if robot == victim for pid in (shell, child)]
    # a client whose own node (the origin) dies is told so, not left waiting
    orphan = t.client(victim, origin_grace=5.0).submit("hang", tag="orphan")
    _marks(t, "orphan")
    for tag, (_, _, robot) in marks.items():
        if robot == victim:
            (t.marks / tag).unlink()  # so the re-placed copy's marks can be read
    t.kill_node(victim)
    assert _gone(doomed) == [], f"{victim}'s executables survived its node"
    with pytest.raises(ProgramLost, match=f"robot {victim}, the origin of this program"):
        orphan.result(RESULT_TIMEOUT)
    assert orphan.state == "failed"
    # each program of the dead robot is placed again and starts on another robot
    for tag, (_, _, robot) in marks.items():
        if robot == victim:
            _, _, again = _marks(t, tag, timeout=60)
            assert again != victim
    for f in futs.values():
        assert f.cancel()
