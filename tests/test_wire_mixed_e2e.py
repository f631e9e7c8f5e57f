"""A team of two releases on real processes, and a node of another major.

How this works: release 0.1.0's code (``src/`` and the test programs at the
tag ``v0.1.0``, taken with ``git archive``, no worktree left behind) runs
robots o1 and o2 with this venv and a ``PYTHONPATH`` of their own; n1 and
n2 run today's code. Round robin spreads each origin's programs over all
four, so an old origin (o1) places on new hosts and a new origin (n1) on old
hosts, its client being today's ``ramps.connect`` in both cases: every
program must come back, from both releases' hosts. Then x2, today's code
with only the protocol major set to 2 (a ``sitecustomize`` on its path: the
envelope a major-2 node would send), joins: today's nodes and x2 log a
refusal naming both versions, 0.1.0 nodes their own version error, and the
team keeps running its programs without x2. Skipped where the tag is not
in the repository (a shallow clone). docs/lab/2026-11-26-mixed-versions.md
has the figures.
"""

from __future__ import annotations

import io
import subprocess
import tarfile
import time
from collections import Counter
from pathlib import Path

import pytest
from runtime_team import LocalTeam, assert_no_leftovers, wait_for

from ramps.core.messages import PROTOCOL

pytestmark = pytest.mark.slow

REPO = Path(__file__).resolve().parent.parent
PREVIOUS = "v0.1.0"
FAKE_MAJOR_2 = """\
# protocol major 2 for this process (tests/test_wire_mixed_e2e.py): today's code otherwise
import ramps.core.messages as m
m.PROTOCOL_MAJOR = m.PROTOCOL_VERSION = 2
m.PROTOCOL_MINOR = 0
m.PROTOCOL = "2.0"
"""


def _previous_release(dest: Path) -> Path | None:
    """Release 0.1.0's ``src`` and test programs under ``dest``, or None without the tag."""
    try:
        data = subprocess.run(["git", "-C", str(REPO), "archive", PREVIOUS, "src", "tests/e2eprogs.py"],
                              capture_output=True, check=True, timeout=60).stdout
    except (OSError, subprocess.SubprocessError):
        return None
    with tarfile.open(fileobj=io.BytesIO(data)) as tar:
        tar.extractall(dest, filter="data")
    return dest


@pytest.fixture(autouse=True, scope="module")
def no_leftover_processes():
    yield
    assert_no_leftovers()


def test_two_releases_run_each_others_programs_and_another_major_is_refused(tmp_path):
    old = _previous_release(tmp_path / "ramps-0.1.0")
    if old is None:
        pytest.skip(f"no tag {PREVIOUS} in this clone (git fetch --tags)")
    old_env = {"PYTHONPATH": f"{old / 'tests'}:{old / 'src'}"}
    with LocalTeam(["n1", "n2"], tmp_path / "logs", cores=2) as t:
        for name in ("o1", "o2"):
            t.start_node(name, extra_env=old_env, wait=False)
        t.wait_visible(["n1", "n2", "o1", "o2"])
        started = time.monotonic()
        both = {}
        for origin in ("o1", "n1"):  # an old origin, a new origin
            team = t.client(origin)
            both[origin] = [team.options(policy="round_robin", timeout=60).submit("where", x=i) for i in range(8)]
        ran: dict[str, Counter] = {}
        for origin, futs in both.items():
            results = [f.result(timeout=90) for f in futs]
            assert [r["x"] for r in results] == list(range(8)), origin
            ran[origin] = Counter(r["robot"] for r in results)
            assert all(f.host == r["robot"] for f, r in zip(futs, results))
        assert ran["o1"]["n1"] + ran["o1"]["n2"] > 0, f"old origin placed nothing on a new host: {ran}"
        assert ran["n1"]["o1"] + ran["n1"]["o2"] > 0, f"new origin placed nothing on an old host: {ran}"
        mixed_s = time.monotonic() - started
        fake = tmp_path / "major2"
        fake.mkdir()
        (fake / "sitecustomize.py").write_text(FAKE_MAJOR_2)
        t.start_node("x2", extra_env={"PYTHONPATH": f"{fake}:{REPO / 'tests'}"}, wait=False)
        refusals = {
            "n1": ("node n1 refuses the messages of 'x2'", "message is version 2, sent by 'x2'",
                   f"this node speaks version {PROTOCOL}"),
            "x2": ("node x2 refuses the messages of ", "message is version 1, sent by ",
                   "this node speaks version 2.0"),
            # 0.1.0's own words (today's say "sent by" and "1.1"): o1 really runs the old code
            "o1": ("protocol version mismatch: message is version 2, this node speaks version 1",),
        }
        joined = time.monotonic()
        named = {}
        for robot, parts in refusals.items():
            wait_for(lambda: all(p in t.logs(robot, tail=200_000) for p in parts), 60,
                     f"{robot} to name both versions\n{t.logs()}")
            named[robot] = round(time.monotonic() - joined, 1)
        # the team keeps working beside x2, which is never a host
        team = t.client("n2")
        after = [team.options(policy="round_robin", timeout=60).submit("where", x=i) for i in range(6)]
        hosts = Counter(f.result(timeout=90)["robot"] for f in after)
        assert "x2" not in hosts and sum(hosts.values()) == 6
        assert "malformed" not in t.logs("n1", tail=200_000)
        print(f"\nold origin o1 -> {dict(ran['o1'])}; new origin n1 -> {dict(ran['n1'])} ({mixed_s:.1f} s); "
              f"x2 named by {named} s after it started; beside it, n2 -> {dict(hosts)}")
        for robot in ("n1", "x2", "o1"):
            print(next(line for line in t.logs(robot, tail=200_000).splitlines() if "version" in line)[:400])
