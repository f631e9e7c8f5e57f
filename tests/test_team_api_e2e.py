"""The Team API against a real team: map, async, per-call timeout, cancel, options."""

from __future__ import annotations

import asyncio
import time
from concurrent.futures import CancelledError

import pytest
from runtime_team import LocalTeam

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def team(tmp_path_factory):
    with LocalTeam(3, tmp_path_factory.mktemp("api"), cores=2) as t:
        client = t.client("r1")
        yield t, client
        client.close()


def wait_idle(client, why: str, timeout: float = 20.0) -> None:
    """Until every robot reports no ramps program running (or fail with ``why``)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if all(r.ramps_running == 0 for r in client.status().robots if r.cores):
            return
        time.sleep(0.2)
    pytest.fail(why)


def test_map_returns_results_in_order(team):
    _, client = team
    out = list(client.map("where", [{"x": i} for i in range(8)]))
    assert [r["x"] for r in out] == list(range(8))


def test_async_variants(team):
    _, client = team

    async def main():
        one = await client.submit_async("where", x=41)
        many = await client.map_async("where", [{"x": i} for i in range(5)])
        opt = await client.options(policy="round_robin").submit_async("where", x=3)
        return one, many, opt

    one, many, opt = asyncio.run(main())
    assert one["x"] == 41 and [r["x"] for r in many] == list(range(5)) and opt["x"] == 3


def test_per_call_timeout_raises_and_withdraws_the_program(team):
    t, client = team
    fut = client.options(timeout=1.0).submit("sleepy", seconds=30, tag="timeout-1")
    with pytest.raises(TimeoutError, match="did not finish in time"):
        fut.result(timeout=30)
    # withdrawn: the worker that ran it is killed and the node takes new work
    wait_idle(client, "the timed-out program kept running on the team")
    assert client.submit("where", x=1).result(timeout=30)["x"] == 1


def test_cancel_withdraws_a_running_program(team):
    _, client = team
    fut = client.submit("sleepy", seconds=30, tag="cancel-1")
    time.sleep(1.0)
    assert fut.cancel()
    with pytest.raises(CancelledError):
        fut.result(timeout=1)
    wait_idle(client, "the cancelled program kept running on the team")


def test_options_local_only_and_policy(team):
    _, client = team
    local = [client.options(local_only=True).submit("where", x=i) for i in range(4)]
    assert {f.result(timeout=30)["robot"] for f in local} == {"r1"}
    rr = [client.options(policy="round_robin").submit("where", x=i) for i in range(6)]
    assert sorted(f.result(timeout=30)["robot"] for f in rr) == ["r1", "r1", "r2", "r2", "r3", "r3"]
    bad = client.options(policy="fastest").submit("where", x=1)
    with pytest.raises(Exception, match="unknown policy 'fastest'"):
        bad.result(timeout=30)


def test_connect_to_a_missing_robot_fails_fast(team):
    import ramps
    from ramps.errors import NoTeam

    t, _ = team
    started = time.monotonic()
    with pytest.raises(NoTeam, match="node 'r9'"):
        ramps.connect(team=t.team, robot="r9", connect=[t.nodes["r1"].endpoint], multicast=False, timeout=1.5)
    assert time.monotonic() - started < 15


def test_a_script_that_never_closes_its_team_still_exits(team):
    """Zenoh runs subscriber callbacks on non-daemon threads: a script that
    forgot ``team.close()`` used to hang forever after its last line."""
    import json
    import subprocess
    import sys

    t, _ = team
    script = ("import json, sys, ramps\n"
              "team = ramps.connect(team=sys.argv[1], robot='r1', connect=json.loads(sys.argv[2]), multicast=False,"
              " timeout=20)\n"
              "print(team.submit('where', x=7).result(timeout=30)['x'])\n")
    started = time.monotonic()
    try:
        out = subprocess.run([sys.executable, "-c", script, t.team, json.dumps(t.endpoints())], capture_output=True,
                             text=True, timeout=90, env=t._env(None))
    except subprocess.TimeoutExpired:
        pytest.fail("the script did not exit after its last line (an open Team kept it alive)")
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "7"
    print(f"script ran and exited in {time.monotonic() - started:.1f} s")
