"""Per-robot revocation of a secured team (issue 14).

Files and signatures (fast): ``ramps team revoke`` signs a list with the team
CA key; a list that was altered, signed by another CA, for another team, or
is not a list at all is refused with a ``CredentialsError`` and nothing else.

End to end (slow, ``LocalTeam(secure=True)``): the list published to a
running team is adopted by every teammate within 2 s, the revoked robot's
node leaves and cannot come back, and the others keep running programs.
"""

from __future__ import annotations

import json
import random
import subprocess
import sys
import time

import msgspec
import pytest
from runtime_team import LocalTeam, assert_no_leftovers

from ramps.errors import CredentialsError
from ramps.runtime import revocation as rv
from ramps.runtime import security as sec

REFUSED_WITHIN = 2.0  # s: the acceptance bound for every teammate


@pytest.fixture(scope="module", autouse=True)
def no_leftover_processes():
    yield
    assert_no_leftovers()


@pytest.fixture
def ca(tmp_path):
    d = tmp_path / "team"
    sec.create_ca(d, "warehouse")
    for r in ("r1", "r2", "r3"):
        sec.issue(d, r)
    return d


def test_revoke_signs_a_list_and_copies_it_into_every_bundle(ca):
    rl, written = rv.revoke(ca, ["r3"])
    assert rl.robots == ["r3"] and rl.seq == 1 and rl.team == "warehouse"
    assert sorted(p.parent.name for p in written) == ["r1", "r2", "r3", "team"]
    ca_cert = sec._load_cert(ca / sec.CA_CERT, "CA")
    for p in written:
        assert rv.load(p, ca_cert, "warehouse") == rl
    rl2, _ = rv.revoke(ca, ["r2"])
    assert rl2.robots == ["r2", "r3"] and rl2.seq == 2
    assert rv.decode(rv.encode(rl2), ca_cert, "warehouse") == rl2


def test_altered_foreign_or_garbage_lists_are_refused(ca, tmp_path):
    rl, _ = rv.revoke(ca, ["r3"])
    ca_cert = sec._load_cert(ca / sec.CA_CERT, "CA")
    with pytest.raises(CredentialsError, match="not signed by the team CA"):
        rv.decode(rv.encode(msgspec.structs.replace(rl, robots=[])), ca_cert, "warehouse")  # r3 unrevoked by r3
    with pytest.raises(CredentialsError, match="not signed by the team CA"):
        rv.decode(rv.encode(msgspec.structs.replace(rl, seq=99)), ca_cert, "warehouse")
    with pytest.raises(CredentialsError, match="for team"):
        rv.decode(rv.encode(rl), ca_cert, "other")
    other = tmp_path / "other"
    sec.create_ca(other, "warehouse")  # same team name, another CA
    forged, _ = rv.revoke(other, ["r1"])
    with pytest.raises(CredentialsError, match="not signed"):
        rv.decode(rv.encode(forged), ca_cert, "warehouse")
    rng = random.Random(14)
    good = rv.encode(rl)
    for _ in range(300):  # every input either is the list or raises the remote error
        data = bytearray(good) if rng.random() < 0.7 else bytearray(rng.randbytes(rng.randrange(0, 200)))
        for _ in range(rng.randrange(1, 4)):
            if data:
                data[rng.randrange(len(data))] = rng.randrange(256)
        try:
            assert rv.decode(bytes(data), ca_cert, "warehouse") == rl
        except CredentialsError:
            pass
    with pytest.raises(CredentialsError, match="over the limit"):
        rv.decode(b"\x00" * (rv.MAX_LIST_BYTES + 1), ca_cert, "warehouse")
    (ca / "r1" / rv.REVOKED_FILE).write_text("{not json")
    with pytest.raises(CredentialsError, match="is not a revocation list"):
        rv.load(ca / "r1" / rv.REVOKED_FILE, ca_cert, "warehouse")


@pytest.mark.slow
def test_cli_revoke_writes_the_list_and_explains(ca):
    run = [sys.executable, "-m", "ramps.cli", "team", "revoke", "r2", "--dir", str(ca)]
    res = subprocess.run(run, capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    assert "revocation list 1 names r2" in res.stdout and "was not told" in res.stdout
    assert json.loads((ca / "r1" / rv.REVOKED_FILE).read_text())["robots"] == ["r2"]
    bad = subprocess.run(run[:-2] + ["--dir", str(ca / "nowhere")], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "no team CA" in bad.stderr


def _trace(path) -> list[dict]:
    try:
        return [json.loads(x) for x in open(path).read().splitlines() if x.strip()]
    except FileNotFoundError:
        return []


@pytest.mark.slow
def test_revoked_robot_is_shut_out_by_every_teammate_and_the_others_keep_running(tmp_path):
    t = LocalTeam(3, tmp_path, cores=2, secure=True)
    traces = {r: tmp_path / f"{r}.trace" for r in ("r1", "r2", "r3")}
    try:
        for r in ("r1", "r2", "r3"):
            t.start_node(r, extra_env={"RAMPS_TRACE": str(traces[r])}, wait=False)
        t.wait_visible(["r1", "r2", "r3"])
        team = t.client("r1")
        before = [team.options(policy="round_robin").submit("where", x=i).result(60)["robot"] for i in range(3)]
        assert "r3" in before  # r3 was a working teammate
        # a teammate without the CA key forges a list shutting r1 out: every node ignores it
        sec.create_ca(tmp_path / "forger", t.team)
        forged, _ = rv.revoke(tmp_path / "forger", ["r1"])
        assert rv.publish(forged, team=t.team, connect=[t.nodes["r2"].endpoint],
                          credentials=str(t.credentials("admin")))[0] >= 1
        time.sleep(1.0)
        assert not any(e["what"] == "revoked" for r in traces for e in _trace(traces[r]))
        assert all(t.nodes[r].proc.poll() is None for r in ("r1", "r2", "r3"))
        assert "not signed by the team CA" in t.logs("r2")
        rl, _ = rv.revoke(t.ca_dir, ["r3"])
        peers, sent_at = rv.publish(rl, team=t.team, connect=[t.nodes["r1"].endpoint],
                                    credentials=str(t.credentials("admin")))
        assert peers >= 1
        # every teammate refuses r3 within 2 s of the list's publication
        deadline = sent_at + 15
        while time.monotonic() < deadline and not all(
                any(e["what"] == "revoked" for e in _trace(traces[r])) for r in ("r1", "r2")):
            time.sleep(0.05)
        for r in ("r1", "r2"):
            got = [e for e in _trace(traces[r]) if e["what"] == "revoked" and e["other"] == "r3"]
            assert got, f"{r} never adopted the list\n{t.logs(r)}"
            assert got[0]["t"] - sent_at < REFUSED_WITHIN, (r, got[0]["t"] - sent_at)
            print(f"{r} shut r3 out {got[0]['t'] - sent_at:.3f} s after the list was published")
        # r3's own node hands its programs back and leaves, saying why
        assert t.nodes["r3"].proc.wait(30) == 2
        assert "revoked" in t.logs("r3")
        # ... and cannot come back: the list is beside its credentials now
        t.start_node("r3", wait=False)
        assert t.nodes["r3"].proc.wait(60) != 0
        assert "is revoked by team" in t.logs("r3")
        # the others keep running programs, none on r3
        after = [f.result(60)["robot"] for f in
                 [team.options(policy="round_robin").submit("where", x=i) for i in range(6)]]
        assert set(after) <= {"r1", "r2"} and len(after) == 6, after
    finally:
        t.close()
