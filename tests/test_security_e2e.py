"""A secured team end to end: real ``ramps node --secure`` processes on loopback
(``runtime_team.LocalTeam(secure=True)``: a team CA, one certificate per robot,
``tls/`` endpoints, multicast off), and strangers trying to get in.

A stranger holds a certificate from another CA that claims the same team
name. Whatever it uses (``ramps.connect``, ``ramps submit``, ``ramps node``, or
a bare Zenoh session that skips every ramps check), it sees no teammate, its
submissions fail with a clear error within 5 s, and no program runs for it;
meanwhile the team keeps running programs across robots. A client without
``--secure`` is told at once that the team is secured.

The one timing assertion is the 5 s acceptance bound on a refusal, measured
in-process; every other wait is a generous upper bound (2-core CI machine).
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import msgspec
import pytest
from runtime_team import LocalTeam, assert_no_leftovers

import ramps
from ramps.core.messages import SubmitProgram, encode
from ramps.errors import CredentialsError, NotAdmitted
from ramps.runtime import security as sec
from ramps.runtime.localteam import free_port

pytestmark = pytest.mark.slow

REFUSED_WITHIN = 5.0  # s: the acceptance bound for a refused peer
RESULT_TIMEOUT = 60.0


@pytest.fixture(scope="module", autouse=True)
def no_leftover_processes():
    yield
    assert_no_leftovers()


@pytest.fixture(scope="module")
def secure3(tmp_path_factory):
    with LocalTeam(3, tmp_path_factory.mktemp("secure3"), cores=2, secure=True) as t:
        yield t


@pytest.fixture(scope="module")
def client(secure3):
    return secure3.client("r1")


@pytest.fixture(scope="module")
def rogue(secure3) -> Path:
    """Robot r9's credentials from another CA, for the same team name."""
    d = secure3.tmp / "rogue-ca"
    sec.create_ca(d, secure3.team)
    return sec.issue(d, "r9")


def settled_totals(client, quiet: float = 2.5, timeout: float = 60.0) -> dict[str, tuple[int, int]]:
    """(accepted_total, finished_total) per robot, once the reports stop changing."""
    deadline = time.monotonic() + timeout
    last, since = None, time.monotonic()
    while True:
        now = {r.robot: (r.accepted_total, r.finished_total) for r in client.status().robots if r.cores}
        if now != last:
            last, since = now, time.monotonic()
        elif time.monotonic() - since >= quiet and len(now) == 3:
            return now
        assert time.monotonic() < deadline, f"load reports never settled: {now}"
        time.sleep(0.2)


def rogue_marks(t: LocalTeam) -> list[str]:
    return sorted(p.name for p in t.marks.iterdir() if p.name.startswith("rogue"))


def raw_session(t: LocalTeam, creds: sec.Credentials):
    """A bare Zenoh peer with the secured team's configuration and ``creds``:
    what a stranger who skips every ramps check would open."""
    import zenoh

    c = zenoh.Config()
    c.insert_json5("mode", '"peer"')
    c.insert_json5("listen/endpoints", "[]")
    c.insert_json5("connect/endpoints", json.dumps(t.endpoints()))
    c.insert_json5("scouting/multicast/enabled", "false")
    for key, value in sec.secure_zenoh_json(t.team, creds).items():
        c.insert_json5(key, json.dumps(value))
    return zenoh.open(c)


def raw_submit(t: LocalTeam, creds: sec.Credentials, tag: str, seconds: float) -> dict:
    """From a bare session: listen to the team for ``seconds`` while sending
    every robot a SubmitProgram of ``sleepy(tag=...)``; what came back."""
    seen = {"load": set(), "alive": set(), "outcomes": 0}
    client_id = f"raw-{tag}"
    with raw_session(t, creds) as s:
        subs = [
            s.declare_subscriber(f"ramps/{t.team}/load/*", lambda smp: seen["load"].add(str(smp.key_expr))),
            s.liveliness().declare_subscriber(f"ramps/{t.team}/alive/*",
                                              lambda smp: seen["alive"].add(str(smp.key_expr)), history=True),
            s.declare_subscriber(f"ramps/{t.team}/client/{client_id}",
                                 lambda smp: seen.__setitem__("outcomes", seen["outcomes"] + 1)),
        ]
        args = msgspec.msgpack.encode({"seconds": 0.1, "tag": tag})
        deadline, rid = time.monotonic() + seconds, 0
        while time.monotonic() < deadline and not (seen["outcomes"] and len(seen["alive"]) >= 3):
            rid += 1
            for robot in ("r1", "r2", "r3"):
                s.put(f"ramps/{t.team}/msg/{robot}", encode(client_id, SubmitProgram(
                    client=client_id, request_id=rid, program="sleepy", args=args)))
            time.sleep(0.3)
        for sub in subs:
            sub.undeclare()
    return seen


# ====================================================================== the team works
def test_secured_team_runs_programs_across_robots(secure3, client):
    futs = [client.options(policy="round_robin").submit("where", x=i) for i in range(6)]
    out = [f.result(timeout=RESULT_TIMEOUT) for f in futs]
    assert [r["x"] for r in out] == list(range(6))
    assert sorted(r["robot"] for r in out) == ["r1", "r1", "r2", "r2", "r3", "r3"]
    assert {r.robot for r in client.status().robots if r.alive} >= {"r1", "r2", "r3"}
    for name in ("r1", "r2", "r3"):
        log = secure3.nodes[name].log.read_text()
        assert "secured: TLS with team certificates" in log and "tls/127.0.0.1" in log
        assert "INSECURE" not in log
    # the command line as a robot's user runs it
    res = secure3.cli("status", "--team", secure3.team, "--secure", "--credentials", str(secure3.credentials("app")),
                      "--connect", secure3.endpoints()[0], "--no-multicast", "--wait", "2", "--json")
    assert res.returncode == 0, res.stderr
    assert {r["robot"] for r in json.loads(res.stdout)["robots"] if r["alive"]} >= {"r1", "r2", "r3"}


# ====================================================================== strangers
def test_stranger_with_another_ca_is_refused_fast_and_nothing_runs_for_it(secure3, client, rogue):
    t = secure3
    before = settled_totals(client)

    # ramps.connect: a clear error well within the bound, though it would wait 30 s for a node
    t0 = time.monotonic()
    with pytest.raises(NotAdmitted, match=r"did not admit robot 'r9'.*certificate from another CA") as info:
        ramps.connect(team=t.team, connect=t.endpoints(), multicast=False, secure=True, credentials=rogue,
                      timeout=30)
    elapsed = time.monotonic() - t0
    print(f"rogue ramps.connect refused after {elapsed:.3f} s: {info.value}")
    assert elapsed < REFUSED_WITHIN

    # ramps submit: prints it, exits non-zero (the time includes starting Python)
    t0 = time.monotonic()
    res = t.cli("submit", "sleepy", "--arg", "tag=rogue-cli", "--team", t.team, "--secure", "--credentials",
                str(rogue), "--no-multicast", *[a for e in t.endpoints() for a in ("--connect", e)], timeout=60)
    cli_elapsed = time.monotonic() - t0
    print(f"rogue `ramps submit` exited {res.returncode} after {cli_elapsed:.3f} s")
    assert res.returncode != 0 and "did not admit robot 'r9'" in res.stderr, res.stderr
    assert cli_elapsed < 30

    # ramps node: refuses to start rather than run alone
    res = t.cli("node", "--robot", "r9", "--team", t.team, "--secure", "--credentials", str(rogue),
                "--listen", f"tls/127.0.0.1:{free_port()}", "--no-multicast", "--speed", "1", "--cores", "1",
                *[a for e in t.endpoints() for a in ("--connect", e)], timeout=60)
    assert res.returncode != 0 and "did not admit robot 'r9'" in res.stderr, res.stderr

    # a bare Zenoh session that skips every ramps check, with the rogue CA, and with the
    # team's own (public) ca.pem next to the foreign certificate: the team's nodes refuse it
    foreign = sec.check_credentials(rogue / sec.BUNDLE_CA, rogue / sec.BUNDLE_CERT, rogue / sec.BUNDLE_KEY)
    trusting = dataclasses.replace(foreign, ca=t.credentials("app") / sec.BUNDLE_CA)
    for name, creds in (("rogue-raw-foreign", foreign), ("rogue-raw-trusting", trusting)):
        seen = raw_submit(t, creds, name, seconds=4)
        assert seen == {"load": set(), "alive": set(), "outcomes": 0}, (name, seen)

    assert settled_totals(client) == before, "a robot accepted a program while only strangers submitted"
    assert rogue_marks(t) == []
    assert all(t.nodes[n].proc.poll() is None for n in ("r1", "r2", "r3"))

    # the same bare session with a team certificate does get in: the checks above are not vacuous
    member = sec.check_credentials(*(t.credentials("raw-app") / f for f in
                                     (sec.BUNDLE_CA, sec.BUNDLE_CERT, sec.BUNDLE_KEY)))
    seen = raw_submit(t, member, "control-raw", seconds=30)
    assert seen["outcomes"] >= 1 and len(seen["alive"]) == 3, seen
    assert (t.marks / "control-raw").exists()


def test_mixed_up_bundle_fails_before_any_network(secure3, rogue):
    """The team's ca.pem with a foreign certificate is caught locally, naming the files."""
    bundle = secure3.tmp / "mixed"
    bundle.mkdir()
    (bundle / sec.BUNDLE_CA).write_bytes((secure3.credentials("app") / sec.BUNDLE_CA).read_bytes())
    for f in (sec.BUNDLE_CERT, sec.BUNDLE_KEY):
        (bundle / f).write_bytes((rogue / f).read_bytes())
    (bundle / sec.BUNDLE_KEY).chmod(0o600)
    with pytest.raises(CredentialsError, match="certificate for r9 .* was not issued by this team's CA"):
        ramps.connect(team=secure3.team, connect=secure3.endpoints(), multicast=False, secure=True,
                      credentials=bundle)


def test_insecure_client_cannot_join_a_secured_team(secure3):
    t = secure3
    plain = [e.replace("tls/", "tcp/") for e in t.endpoints()]
    t0 = time.monotonic()
    with pytest.raises(NotAdmitted, match=r"is secured \(TLS, team certificates\) and this client is not"):
        ramps.connect(team=t.team, connect=plain, multicast=False, timeout=30)
    elapsed = time.monotonic() - t0
    print(f"insecure ramps.connect refused after {elapsed:.3f} s")
    assert elapsed < REFUSED_WITHIN
    res = t.cli("submit", "where", "--team", t.team, "--no-multicast", "--connect", plain[0], timeout=60)
    assert res.returncode != 0 and "--secure" in res.stderr, res.stderr
    # tls/ endpoints without --secure: a configuration error, at once
    res = t.cli("submit", "where", "--team", t.team, "--no-multicast", "--connect", t.endpoints()[0], timeout=60)
    assert res.returncode == 2 and "TLS links need secure mode" in res.stderr, res.stderr


# ====================================================================== a team of its own
def test_first_secure_node_starts_alone_and_others_join(tmp_path):
    """The first robot up lists a teammate that is not up yet: it starts anyway
    (no fail-fast against nobody), and the next robot joins it."""
    t = LocalTeam(0, tmp_path, cores=1, secure=True)
    try:
        t.start_node("r1", extra_args=["--connect", f"tls/127.0.0.1:{free_port()}"])
        t.start_node("r2")
        c = t.client("r1")
        futs = [c.options(policy="round_robin").submit("where", x=i) for i in range(4)]
        assert sorted(f.result(timeout=RESULT_TIMEOUT)["robot"] for f in futs) == ["r1", "r1", "r2", "r2"]
    finally:
        t.close()
