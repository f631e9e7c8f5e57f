"""End to end: a real node flooded with malformed messages keeps working.

Two ``ramps node`` processes on loopback (``runtime_team.LocalTeam``: explicit
endpoints, multicast off). While robot r1's client submits legitimate
programs (``burn`` and ``echo``, through ``ramps.connect``), a separate Zenoh
session sends 5,000 malformed messages within about 5 s to r1's inbox and
to the team's load keys (r1 hears periodic reports' and those of the
instant, r2, which places nothing, those of the instant): garbage,
truncated and bit-flipped messages, other protocol versions, the wrong
shape, fields out of their limits, pickles, deep nesting and payloads of
1-9 MB. The flooder blocks rather than drops when Zenoh's queues are full, so
every message reaches the nodes and their counters (``bad_messages``, in
their load reports) must match what was sent, one for one. Every program
must complete with the right result, both nodes must live, and r1's private
resident memory may grow by less than 50 MB.

Why private, and why it holds (measured with the backlog and /proc/<pid>/status
sampled inside the node, 2026-11-23, a CPU hog beside): during the flood the
node's heap grows by up to its backlog (``MAX_BACKLOG_BYTES``, 64 MiB: a
slowed node reached 60 MiB and dropped 3 messages) plus the messages in
flight, 120 MB over its baseline at the peak; glibc then kept 30-60 MB of it
after the flood, which is what failed this test now and then (58-79 MB). The
node now gives a drained burst back (``ramps.runtime.heap``: ``malloc_trim``
once 16 MiB went through). Shared memory is left out: 16-19 MiB of Zenoh
shared-memory segment are mapped into both nodes when a peer's first large
message arrives (the client's or the teammate's; the flooder has shared
memory off), at a moment this test does not choose, flood or no flood. ``ramps bench flood`` runs the same
flood (sender dropping under congestion) and prints the figures.
"""

from __future__ import annotations

import re
import time

import psutil
import pytest
from runtime_team import LocalTeam

from ramps.bench.flood import flood_team

pytestmark = pytest.mark.slow

MESSAGES = 5_000  # ``ramps bench flood`` runs longer floods
SECONDS = 5.0
PROGRAMS = 40


def test_flooded_node_runs_every_program_counts_every_drop_and_stays_small(tmp_path):
    with LocalTeam(2, tmp_path, cores=2) as t:
        client = t.client("r1")
        pids = {name: node.pid for name, node in t.nodes.items()}
        res = flood_team(team=t.team, endpoints=t.endpoints(), target="r1", pids=pids, client=client,
                         messages=MESSAGES, seconds=SECONDS, programs=PROGRAMS, block=True)
        summary = {k: res[k] for k in ("messages_sent", "flood_seconds", "dropped_counted", "expected_at_target",
                                       "expected_at_others", "programs_ok", "program_hosts", "rss_before_mb",
                                       "rss_after_mb", "rss_peak_mb", "private_before_mb", "private_after_mb",
                                       "failures")}
        print(summary)  # the figures, for the record (pytest -s)
        assert res["messages_sent"] == MESSAGES and res["send_errors"] == 0
        assert res["big_messages"] > 0 and res["to_load_key"] > 0
        # within about the time asked (the sender only waits when the nodes' links are full)
        assert res["flood_seconds"] < 3 * SECONDS, summary
        # every legitimate program completed, once, with its own result
        assert (res["programs_ok"], res["programs_failed"], res["programs_wrong"]) == (PROGRAMS, 0, 0), summary
        # every malformed message was dropped and counted, none twice
        assert res["dropped_counted"] == {"r1": res["expected_at_target"], "r2": res["expected_at_others"]}, summary
        assert all(res["alive"].values()) and all(n.proc.poll() is None for n in t.nodes.values()), t.logs()
        growth = res["private_growth_mb"]["r1"]
        assert growth < 50, f"r1's private memory grew by {growth:.1f} MB: {summary}"
        # still serving after the flood
        assert client.submit("echo", after=1).result(timeout=60) == {"after": 1}
        # the log says so too: a few lines for the whole flood, and the total on the way out
        assert t.stop_node("r1") == 0
        log = t.nodes["r1"].log.read_text(errors="replace")
        lines = log.count("dropped a message")
        assert 1 <= lines <= res["flood_seconds"] + res["programs_seconds"] + 60, lines
        total = re.search(r"dropped (\d+) malformed message\(s\) and (\d+) over its backlog", log)
        assert total and int(total.group(1)) + int(total.group(2)) >= res["dropped_counted"]["r1"], log[-2000:]


def test_node_process_memory_is_measured_on_the_node_not_its_workers(tmp_path):
    """The RSS above is the node's own process (its workers are processes of
    their own: children of the node's fork server, itself the node's child)."""
    with LocalTeam(1, tmp_path, cores=1) as t:
        node = psutil.Process(t.nodes["r1"].pid)
        deadline = time.monotonic() + 30
        while not t.worker_pids("r1") and time.monotonic() < deadline:
            time.sleep(0.1)
        workers = t.worker_pids("r1")
        assert workers and node.pid not in workers
        assert all(psutil.Process(psutil.Process(w).ppid()).ppid() == node.pid for w in workers)
