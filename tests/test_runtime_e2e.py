"""End to end: real ``ramps node`` processes on loopback, real Zenoh, real workers.

Each test talks to a team of ``python -m ramps.cli node`` processes started
by ``runtime_team.LocalTeam`` (tests/runtime_team.py) running the programs in
tests/e2eprogs.py. Nodes are started with ``RAMPS_ROBOT`` set, so a result
says which robot ran it. Tests that only submit share one three-robot team;
tests that stop, kill, add or load robots get their own.

No assertion depends on how fast anything is: timeouts are generous upper
bounds (a 2-core CI machine runs four nodes and their workers at once).
"""

from __future__ import annotations

import ast
import json
import os
import pickle
import signal
import subprocess
import sys
import time
from collections import Counter
from pathlib import Path

import msgspec
import psutil
import pytest
from runtime_team import _STARTED as STARTED
from runtime_team import LocalTeam, assert_no_leftovers, cgroup_support, wait_for

import ramps
from ramps.core.messages import ProgramOutcome, SubmitProgram, decode, encode
from ramps.errors import BadArguments, ProgramFailed, ProgramNotFound, ProgramRefused
from ramps.runtime.registry import MAX_ARGS_BYTES

pytestmark = pytest.mark.slow

RESULT_TIMEOUT = 60.0
SRC = Path(ramps.__file__).resolve().parent


# ====================================================================== fixtures
@pytest.fixture(scope="module", autouse=True)
def no_leftover_processes():
    """After this module: no node, worker, load or CLI process of this run is alive."""
    yield
    assert_no_leftovers()
    # and the plain way: no `ramps.cli node` this run started is in the process table
    ps = subprocess.run(["pgrep", "-f", "ramps.cli node"], capture_output=True, text=True)
    running = {int(x) for x in ps.stdout.split()}
    ours = {p.pid for p in STARTED}
    assert not running & ours, f"ramps nodes of this run still running: {sorted(running & ours)}"


@pytest.fixture(scope="module")
def team3(tmp_path_factory):
    """Three robots, two cores each, shared by the tests that do not disturb the team."""
    with LocalTeam(3, tmp_path_factory.mktemp("team3"), cores=2) as t:
        yield t


@pytest.fixture(scope="module")
def clients(team3):
    """One Team connection per robot, each robot the origin of its client's programs."""
    return {r: team3.client(r) for r in ("r1", "r2", "r3")}


def results(futs, timeout=RESULT_TIMEOUT):
    return [f.result(timeout=timeout) for f in futs]


def assert_team_healthy(t: LocalTeam, clients: dict) -> None:
    """Every node process is up and each robot, as origin, still gets a program done."""
    for name in ("r1", "r2", "r3"):
        assert t.nodes[name].proc.poll() is None, f"node {name} exited\n{t.logs(name)}"
    for name, team in clients.items():
        r = team.submit("where", x=7).result(timeout=RESULT_TIMEOUT)
        assert r["x"] == 7 and r["robot"] in ("r1", "r2", "r3"), (name, r)


def robot_processes(t: LocalTeam, robot: str) -> list[psutil.Process]:
    """Live processes of ``robot`` (its node and workers carry RAMPS_ROBOT)."""
    out = []
    for p in t.leftovers():
        try:
            if p.environ().get("RAMPS_ROBOT") == robot:
                out.append(p)
        except psutil.Error:
            continue
    return out


def read_marks(t: LocalTeam) -> dict[str, tuple[str, int]]:
    """tag -> (robot, worker pid) of every sleepy(tag=...) that has started."""
    out = {}
    for p in t.marks.iterdir():
        if p.suffix == ".tmp":
            continue
        try:
            robot, pid = p.read_text().split()
        except (OSError, ValueError):
            continue
        out[p.name] = (robot, int(pid))
    return out


# ====================================================================== shared team
def test_every_future_resolves_exactly_once(team3, clients):
    futs = [clients["r1"].submit("where", x=i) for i in range(12)]
    res = results(futs)
    assert sorted(r["x"] for r in res) == list(range(12))
    assert {r["robot"] for r in res} <= {"r1", "r2", "r3"}
    assert all(isinstance(r["pid"], int) and r["pid"] > 0 for r in res)
    # the pids are worker processes of the robot that says it ran them
    # (workers may be replaced later, so only check the ones still alive)
    for r in res:
        try:
            parent = psutil.Process(r["pid"]).parent()
        except psutil.NoSuchProcess:
            continue
        assert r["pid"] in team3.worker_pids(r["robot"]), (r, parent)


def test_programs_spread_across_robots(team3, clients):
    """9 one-second programs from r1 on three 2-core robots: r1 cannot hold them all
    (a long run queue is avoided), so more than one robot runs them."""
    futs = [clients["r1"].submit("sleepy", seconds=1.0) for _ in range(9)]
    ran = Counter(r["robot"] for r in results(futs))
    assert sum(ran.values()) == 9
    assert len(ran) >= 2, f"every program ran on one robot: {dict(ran)}"


def test_cpu_programs_spread_across_robots(team3, clients):
    futs = [clients["r2"].submit("spin", seconds=0.3) for _ in range(6)]
    ran = Counter(results(futs))
    assert sum(ran.values()) == 6 and set(ran) <= {"r1", "r2", "r3"}
    assert len(ran) >= 2, f"every program ran on one robot: {dict(ran)}"


def test_big_result_crosses_the_network(team3, clients):
    res = results([clients["r1"].submit("big", n=200_000) for _ in range(3)])
    assert [len(r) for r in res] == [200_000] * 3 and all(set(r) == {ord("x")} for r in res)


def test_program_that_raises_is_program_failed(team3, clients):
    fut = clients["r1"].submit("fail")
    with pytest.raises(ProgramFailed) as ei:
        fut.result(timeout=RESULT_TIMEOUT)
    assert "no route to the dock" in str(ei.value)
    assert "ValueError" in str(ei.value)
    assert ei.value.host in ("r1", "r2", "r3")
    assert_team_healthy(team3, clients)


def test_unknown_program_is_refused_at_the_caller(team3, clients):
    t0 = time.monotonic()
    try:
        fut = clients["r1"].submit("no_such_program", x=1)
    except ProgramNotFound:  # a client that knows the team's registry may say so at once
        pass
    else:
        with pytest.raises(ProgramRefused) as ei:
            fut.result(timeout=RESULT_TIMEOUT)
        assert "no_such_program" in str(ei.value)
    assert time.monotonic() - t0 < 30, "a refusal should not wait for a timeout"
    assert_team_healthy(team3, clients)


def test_bad_arguments_fail_at_the_caller(team3, clients):
    team = clients["r1"]
    # not in the program's signature: the origin node checks before placing anything
    with pytest.raises(BadArguments) as ei:
        team.submit("where", y=1).result(timeout=RESULT_TIMEOUT)
    assert "where" in str(ei.value)
    with pytest.raises(BadArguments):
        team.submit("big").result(timeout=RESULT_TIMEOUT)  # missing n
    # cannot be encoded with msgpack (nothing is pickled): refused before sending
    with pytest.raises(BadArguments):
        team.submit("where", x=object())
    assert_team_healthy(team3, clients)


def test_oversized_arguments_fail_at_submit(team3, clients):
    with pytest.raises(BadArguments) as ei:
        clients["r1"].submit("where", x=b"\0" * (MAX_ARGS_BYTES + 10))
    assert "limit" in str(ei.value)
    assert clients["r1"].pending() == 0
    assert_team_healthy(team3, clients)


def test_worker_killed_mid_program_is_replaced_elsewhere(team3, clients):
    """SIGKILL the worker process (not the node) running a program: the node
    reports it retryable and the origin places the program on another robot."""
    fut = clients["r1"].submit("sleepy", seconds=3.0, tag="victim")
    robot, pid = wait_for(lambda: read_marks(team3).get("victim"), 30, "the program to start")
    # it is one of that node's worker processes, not the node
    assert pid in team3.worker_pids(robot), (robot, pid, team3.worker_pids(robot))
    assert pid != team3.nodes[robot].pid
    os.kill(pid, signal.SIGKILL)
    res = fut.result(timeout=RESULT_TIMEOUT)
    assert res["tag"] == "victim"
    assert res["pid"] != pid
    assert res["robot"] != robot, "a program whose worker died is placed on another robot"
    # the node survived and keeps a full pool (a fresh worker replaced the dead one)
    assert team3.nodes[robot].proc.poll() is None
    wait_for(lambda: len(team3.worker_pids(robot)) == 2, 30, f"{robot} to refill its worker pool")
    assert_team_healthy(team3, clients)


def test_cli_submit_and_status(team3):
    eps = [a for ep in team3.endpoints() for a in ("--connect", ep)]
    sub = team3.cli("submit", "where", "--arg", "x=5", "--count", "2", "--team", team3.team, "--robot", "r1",
                    *eps, "--no-multicast", "--json")
    assert sub.returncode == 0, sub.stderr
    lines = [json.loads(line) for line in sub.stdout.splitlines() if line.strip()]
    assert len(lines) == 2 and all(line["ok"] for line in lines), sub.stdout
    assert all(line["value"]["x"] == 5 and line["value"]["robot"] in ("r1", "r2", "r3") for line in lines)

    fail = team3.cli("submit", "fail", "--team", team3.team, "--robot", "r1", *eps, "--no-multicast", "--json")
    assert fail.returncode == 1, (fail.stdout, fail.stderr)
    assert "no route to the dock" in fail.stdout

    st = team3.cli("status", "--team", team3.team, *eps, "--no-multicast", "--json", "--wait", "2.5")
    assert st.returncode == 0, st.stderr
    data = json.loads(st.stdout)
    assert data["team"] == team3.team
    robots = {r["robot"]: r for r in data["robots"]}
    assert set(robots) == {"r1", "r2", "r3"}
    for r in robots.values():
        assert r["alive"], r
        assert r["cores"] == 2 and r["report_age"] is not None, r
        assert r["sees"] == 2, r  # each robot's own view holds both teammates
    assert "sees" in team3.cli("status", "--team", team3.team, *eps, "--no-multicast", "--wait", "1").stdout

    # each robot lists the links it measured to both teammates (probes every 5 s), and r1 the work it
    # learned of the program it placed (issue 10)
    def measured():
        st = team3.cli("status", "--team", team3.team, *eps, "--no-multicast", "--json", "--wait", "1.5")
        rows = {r["robot"]: r for r in json.loads(st.stdout)["robots"]} if st.returncode == 0 else {}
        full = len(rows) == 3 and all({link[0] for link in r["links"]} == set(rows) - {name}
                                      for name, r in rows.items())
        return rows if full else None

    robots = wait_for(measured, 30, "every robot's status listing its links to both teammates")
    assert all(link[1] is not None and 0 <= link[1] < 1.0 for r in robots.values() for link in r["links"])
    # "where" returns at once: too short to learn from (MIN_RUN_WORK); a spin of 0.3 s is not
    assert "where" not in {w[0] for w in robots["r1"]["learned"]}, robots["r1"]
    spin = team3.cli("submit", "spin", "--arg", "seconds=0.3", "--team", team3.team, "--robot", "r1", *eps,
                     "--no-multicast", "--json")
    assert spin.returncode == 0, spin.stderr
    robots = wait_for(lambda: (r := measured()) and "spin" in {w[0] for w in r["r1"]["learned"]} and r, 30,
                      "r1's status listing the work it learned of spin")
    table = team3.cli("status", "--team", team3.team, *eps, "--no-multicast", "--wait", "1.5").stdout
    assert "links each robot measured" in table and "work learned" in table


# ---------------------------------------------------------------- nothing pickled
FORBIDDEN = {"pickle", "_pickle", "cPickle", "cloudpickle", "dill", "marshal", "shelve", "copyreg",
             "multiprocessing"}
#: copyreg and marshal are loaded by every interpreter at start-up
LOADED_FORBIDDEN = FORBIDDEN - {"copyreg", "marshal"}


def test_no_pickle_in_the_wire_paths():
    """Static: no module of ramps.core or ramps.runtime imports a pickler
    (multiprocessing pickles too); dynamic: importing the runtime pulls none in."""
    offenders = []
    for pkg in ("core", "runtime"):
        for path in sorted((SRC / pkg).rglob("*.py")):
            tree = ast.parse(path.read_text(), filename=str(path))
            for node in ast.walk(tree):
                names = []
                if isinstance(node, ast.Import):
                    names = [a.name for a in node.names]
                elif isinstance(node, ast.ImportFrom) and node.module:
                    names = [node.module]
                elif isinstance(node, ast.Call) and getattr(node.func, "id", "") == "__import__":
                    names = [a.value for a in node.args[:1] if isinstance(a, ast.Constant)]
                for name in names:
                    if str(name).split(".")[0] in FORBIDDEN:
                        offenders.append(f"{path.relative_to(SRC)}:{node.lineno} imports {name}")
                if isinstance(node, ast.Attribute) and node.attr in ("ProcessPoolExecutor",):
                    offenders.append(f"{path.relative_to(SRC)}:{node.lineno} uses {node.attr}")
    assert not offenders, offenders
    code = ("import sys; import ramps.core.messages, ramps.runtime.node, ramps.runtime.client, "
            "ramps.runtime.worker, ramps.runtime.workers; "
            f"print(sorted(m for m in sys.modules if m.split('.')[0] in {sorted(LOADED_FORBIDDEN)!r}))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]", out.stdout


class _Tripwire:
    """Unpickling this creates a file: proof that someone unpickled it."""

    def __init__(self, path: str) -> None:
        self.path = path

    def __reduce__(self):
        return (open, (self.path, "w"))


def _raw_session(t: LocalTeam):
    import zenoh

    c = zenoh.Config()
    c.insert_json5("mode", '"peer"')
    c.insert_json5("listen/endpoints", "[]")
    c.insert_json5("connect/endpoints", json.dumps(t.endpoints()))
    c.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(c)


def _drops(t: LocalTeam, robot: str) -> int:
    return t.nodes[robot].log.read_text(errors="replace").count("dropped a message")


def test_pickled_message_is_dropped_and_counted(team3, clients, tmp_path):
    """A raw Zenoh put of a pickled object to a node's inbox (and to the load
    key every node hears) is dropped and logged; nothing is unpickled, no node
    crashes, and programs still run everywhere."""
    tripwire = tmp_path / "unpickled"
    payload = pickle.dumps({"type": "submit", "evil": _Tripwire(str(tripwire))}, protocol=pickle.HIGHEST_PROTOCOL)
    before = {r: _drops(team3, r) for r in ("r1", "r2", "r3")}
    with _raw_session(team3) as s:
        # a put made before Zenoh has matched the subscriber can vanish: repeat until the node saw one
        deadline = time.monotonic() + 30
        while _drops(team3, "r2") == before["r2"]:
            assert time.monotonic() < deadline, f"r2 never logged the dropped message\n{team3.logs('r2')}"
            s.put(f"ramps/{team3.team}/msg/r2", payload)
            time.sleep(0.3)
        deadline = time.monotonic() + 30
        while any(_drops(team3, r) <= before[r] for r in ("r1", "r3")):
            assert time.monotonic() < deadline, "the load key's subscribers never logged the drop\n" + team3.logs()
            s.put(f"ramps/{team3.team}/load/r9", payload)
            time.sleep(0.3)
    assert not tripwire.exists(), "a node unpickled a message"
    assert "not a ramps message" in team3.nodes["r2"].log.read_text() or \
        "malformed ramps message" in team3.nodes["r2"].log.read_text()
    assert_team_healthy(team3, clients)


def test_node_checks_argument_size_itself(team3, clients):
    """A client that skips the size check (a raw SubmitProgram with 100 bytes
    more arguments than the limit, still one message) gets a bad_arguments
    outcome from the node."""
    client_id = "raw-e2e-client"
    got = []
    args = msgspec.msgpack.encode({"x": "a" * (MAX_ARGS_BYTES + 100)})
    with _raw_session(team3) as s:
        sub = s.declare_subscriber(f"ramps/{team3.team}/client/{client_id}",
                                   lambda smp: got.append(decode(smp.payload.to_bytes()).msg))
        try:
            deadline = time.monotonic() + 30
            rid = 0
            while not got:
                assert time.monotonic() < deadline, "no outcome for the oversized submission\n" + team3.logs("r1")
                rid += 1
                s.put(f"ramps/{team3.team}/msg/r1", encode(client_id, SubmitProgram(
                    client=client_id, request_id=rid, program="where", args=args)))
                time.sleep(0.5)
        finally:
            sub.undeclare()
    o = got[0]
    assert isinstance(o, ProgramOutcome) and not o.ok
    assert o.error_kind == "bad_arguments" and "limit" in o.error, o
    assert_team_healthy(team3, clients)


# ====================================================================== teams of their own
def test_node_joining_mid_run_gets_later_programs(tmp_path):
    with LocalTeam(3, tmp_path, cores=2) as t:
        team = t.client("r1")
        first = results([team.submit("sleepy", seconds=0.5) for _ in range(6)])
        assert {r["robot"] for r in first} <= {"r1", "r2", "r3"}
        t.start_node("r4")  # waits until r4's token and load reports are seen
        # eight programs for eight free cores: the least utilised robots get them (a program
        # that computes: sleepy's runs used next to no CPU, so r1 learned that it costs
        # nothing and would keep it, rightly)
        second = Counter(results([team.submit("spin", seconds=1.5) for _ in range(8)]))
        assert sum(second.values()) == 8
        assert second["r4"] >= 1, f"the new robot r4 got none of the second wave: {dict(second)}"


def test_node_leaving_hands_its_programs_back(tmp_path):
    """SIGTERM a robot while it runs programs: it hands them back, its origin
    places them elsewhere, every future still resolves, none is lost or doubled.
    The robot stopped is a teammate of the origin that started one of them
    (r2 or r3: which one the origin picks depends on the loads it saw)."""
    with LocalTeam(3, tmp_path, cores=2, verbose=True) as t:
        team = t.client("r1")
        tags = [f"p{i}" for i in range(6)]
        futs = {tag: team.submit("sleepy", seconds=4.0, tag=tag) for tag in tags}
        marks = wait_for(lambda: (m := read_marks(t)) and any(r != "r1" for r, _ in m.values()) and m,
                         30, "a teammate of r1 to start one of the programs")
        gone = sorted(r for r, _ in marks.values() if r != "r1")[0]
        stays = ({"r2", "r3"} - {gone}).pop()
        on_gone = {tag for tag, (robot, _) in marks.items() if robot == gone}
        rc = t.stop_node(gone, signal.SIGTERM)
        assert rc == 0, t.logs(gone)
        assert "handing running programs back" in t.nodes[gone].log.read_text()
        res = {tag: f.result(timeout=RESULT_TIMEOUT) for tag, f in futs.items()}
        assert sorted(r["tag"] for r in res.values()) == tags
        for tag in on_gone:
            assert res[tag]["robot"] in ("r1", stays), (tag, res[tag])
        # r1 heard each of them back from the robot leaving (a retryable "shutting
        # down" result, re-placed at once), not just lost it and timed out on it
        handed = t.nodes["r1"].log.read_text().count(f"worker lost: {gone} is shutting down")
        assert handed >= len(on_gone), t.logs("r1")
        # its workers went with it
        wait_for(lambda: not robot_processes(t, gone), 15, f"{gone}'s worker processes to exit")
        # the rest of the team carries on
        again = results([team.submit("where", x=i) for i in range(4)])
        assert {r["robot"] for r in again} <= {"r1", stays}
        # and the robots left say so in their reports: each sees one teammate now
        wait_for(lambda: {r.robot: r.sees for r in team.status().robots if r.alive} == {"r1": 1, stays: 1},
                 15, f"r1 and {stays} to report that each sees one teammate")


CGROUP_WHY_NOT = cgroup_support()


@pytest.mark.serial  # robots of one core each, one of them busy: measured loads need the CPU they were given
@pytest.mark.skipif(CGROUP_WHY_NOT is not None, reason=f"cpu cgroups unavailable: {CGROUP_WHY_NOT}")
def test_loaded_robot_gets_fewer_programs_cgroups(tmp_path):
    """Four robots, each its own cpu cgroup with a quota of one core (so each
    node measures its own cgroup and detects one core); r4 also runs three busy
    loops inside its cgroup. r1 places six programs: the three unloaded robots
    take them and the loaded one gets fewer than any of them."""
    with LocalTeam(4, tmp_path, cores=None, cgroups=True, quota_cores=1.0) as t:
        team = t.client("r1")
        for i in range(3):
            t.spawn([sys.executable, "-c", "while True: pass"], robot="r4", name=f"busy{i}")

        def loaded():  # every robot reported (a robot alive but not heard from yet has a row of defaults)
            st = {r.robot: r for r in team.status().robots if r.report_age is not None}
            return all(n in st for n in ("r1", "r2", "r3", "r4")) and st["r4"].runnable >= 2.0 and st
        st = wait_for(loaded, 30, "r4 to report its background load", poll=0.2)
        assert all(st[n].cores == 1 for n in st), st
        assert max(st[n].runnable for n in ("r1", "r2", "r3")) < st["r4"].runnable
        # each node reports the CPU it uses itself (a few percent of a core, never all of it;
        # an idle one that places nothing may not have used a 10 ms tick of it yet)
        cpu = {n: st[n].node_cpu for n in st}
        assert all(0.0 <= c < 0.5 for c in cpu.values()) and any(c > 0.0 for c in cpu.values()), cpu
        ran = Counter(r["robot"] for r in results([team.submit("sleepy", seconds=1.5) for _ in range(6)]))
        assert sum(ran.values()) == 6
        assert ran["r4"] < min(ran[n] for n in ("r1", "r2", "r3")), dict(ran)


@pytest.mark.skipif(CGROUP_WHY_NOT is None, reason="cpu cgroups available: the cgroup test covers this")
def test_smaller_robot_gets_fewer_programs_no_cgroups(tmp_path):
    """Fallback without cpu cgroups: nodes on one host all measure the same
    host-wide load, so background load cannot be given to one robot honestly.
    Instead r3 offers one core and r1, r2 four: r1 places eight programs and
    the small robot, with the longer run queue per core, gets the fewest."""
    with LocalTeam(2, tmp_path, cores=4) as t:
        t.start_node("r3", cores=1)
        team = t.client("r1")
        ran = Counter(r["robot"] for r in results([team.submit("sleepy", seconds=1.5) for _ in range(8)]))
        assert sum(ran.values()) == 8
        assert ran["r3"] < min(ran["r1"], ran["r2"]), dict(ran)


# ---------------------------------------------------------------- results larger than the limits
@pytest.fixture(scope="module")
def team2(tmp_path_factory):
    with LocalTeam(2, tmp_path_factory.mktemp("team2"), cores=2) as t:
        yield t


def test_result_over_one_mib_from_a_teammate_is_accepted(team2):
    team = team2.client("r1")
    res = results([team.submit("big", n=2_000_000) for _ in range(4)])
    assert [len(r) for r in res] == [2_000_000] * 4  # they do arrive, in the end ...
    # ... but only after r1 dropped r2's results, wrote r2 off (heartbeat timeout) and ran them again
    log = team2.nodes["r1"].log.read_text()
    assert "exceeds the limit" not in log, log[-2000:]


def test_result_over_eight_mib_resolves_the_future(team2):
    team = team2.client("r1")
    fut = team.options(local_only=True).submit("big", n=9_000_000)  # r1 runs it: no teammate involved
    with pytest.raises(ramps.errors.ProgramFailed, match="results are limited to"):
        fut.result(timeout=30)
