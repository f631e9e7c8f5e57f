"""Roll a team of ramps 0.1.0 nodes forward to today's code while it works (a lab script).

How this works: release 0.1.0's code (``git archive v0.1.0``, run with this
venv and its own ``PYTHONPATH``) starts robots r1..rN on loopback
(``tests/runtime_team.LocalTeam``). An application on r1 submits ``spin``
programs continuously through round robin (so every robot hosts some); the
hosts r2..rN are then upgraded one at a time (SIGTERM: a node hands its
programs back; start today's code under the same name; wait until the team
sees it), and last r1 itself, once its application's programs are all in
(a 0.1.0 origin keeps its programs only while it runs). A final batch runs
on the all-new team. Prints one JSON line: per phase, programs delivered,
failed, where they ran and on which release. Used for
docs/lab/2026-11-26-mixed-versions.md; not part of the test suite.

    .venv/bin/python tests/golden/rolling_upgrade.py [--robots 4] [--gap 4]
"""

from __future__ import annotations

import argparse
import io
import json
import subprocess
import sys
import tarfile
import tempfile
import threading
import time
from collections import Counter
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO / "tests"))

from runtime_team import LocalTeam  # noqa: E402


def others(t: LocalTeam, name: str) -> list[str]:
    """``--connect`` to every running teammate (a restarted node listens on a
    new port, so the first node's endpoint may be gone)."""
    return [arg for n in t.alive() if n != name for arg in ("--connect", t.nodes[n].endpoint)]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--robots", type=int, default=4)
    ap.add_argument("--gap", type=float, default=4.0, help="seconds between two upgrades")
    ap.add_argument("--spin", type=float, default=0.2, help="CPU seconds per program")
    ap.add_argument("--rate", type=float, default=1.0, help="programs submitted per second")
    ap.add_argument("--to", choices=("new", "old"), default="new",
                    help="restart the nodes as today's code (an upgrade) or as 0.1.0 again (the baseline)")
    ap.add_argument("--timeout", type=float, default=0.0, help="each program's timeout, s (0: none)")
    ap.add_argument("--wait", type=float, default=600.0, help="longest wait for every outcome once the roll is over")
    a = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="ramps-roll-"))
    data = subprocess.run(["git", "-C", str(REPO), "archive", "v0.1.0", "src", "tests/e2eprogs.py"],
                          capture_output=True, check=True).stdout
    with tarfile.open(fileobj=io.BytesIO(data)) as tar:
        tar.extractall(tmp / "old", filter="data")
    old_env = {"PYTHONPATH": f"{tmp / 'old' / 'tests'}:{tmp / 'old' / 'src'}"}
    names = [f"r{i}" for i in range(1, a.robots + 1)]
    to_env, to_release = (None, "0.2.0") if a.to == "new" else (old_env, "0.1.0")
    release = {n: "0.1.0" for n in names}
    phases: list[dict] = []
    t = LocalTeam([], tmp / "logs", cores=2)  # started by hand below: nodes of two releases
    try:
        for n in names:
            t.start_node(n, extra_env=old_env, wait=False)
        t.wait_visible(names)
        team = t.client("r1")
        futs: list[tuple[str, float, object]] = []
        phase = ["all 0.1.0"]
        stop = threading.Event()
        done_at: dict[int, float] = {}

        def submit() -> None:
            i = 0
            while not stop.is_set():
                fut = team.options(policy="round_robin", timeout=a.timeout or None).submit("spin", seconds=a.spin)
                fut.add_done_callback(lambda f: done_at.__setitem__(id(f), time.monotonic()))
                futs.append((phase[0], time.monotonic(), fut))
                i += 1
                time.sleep(1.0 / a.rate)

        th = threading.Thread(target=submit, daemon=True)
        started = time.monotonic()
        th.start()
        time.sleep(a.gap)
        upgrades = []
        for n in reversed(names[1:]):
            t0 = time.monotonic()
            t.stop_node(n)
            phase[0] = f"{n} upgrading"
            t.start_node(n, extra_env=to_env, extra_args=others(t, n))  # waits until visible
            release[n] = to_release
            upgrades.append({"robot": n, "seconds_out": round(time.monotonic() - t0, 2)})
            phase[0] = f"after {n}"
            time.sleep(a.gap)
        stop.set()
        th.join()
        rolled = time.monotonic() - started
        results = []
        deadline = time.monotonic() + a.wait
        for ph, at, f in futs:
            try:
                host = f.result(timeout=max(0.0, deadline - time.monotonic()))
                # the host's release when every outcome was in
                results.append((ph, host, release.get(host), None, done_at.get(id(f), time.monotonic()) - at))
            except Exception as exc:  # noqa: BLE001 - counted and printed
                results.append((ph, None, None, f"{type(exc).__name__}: {exc}"[:200], None))
        ran_on = Counter()
        for ph, host, rel, err, _ in results:
            ran_on[(host, rel)] += 1
        # r1 last: its own programs are all in
        t0 = time.monotonic()
        team.close()
        t.stop_node("r1")
        t.start_node("r1", extra_env=to_env, extra_args=others(t, "r1"))
        release["r1"] = to_release
        upgrades.append({"robot": "r1", "seconds_out": round(time.monotonic() - t0, 2)})
        team = t.client("r1")
        rr = team.options(policy="round_robin", timeout=a.timeout or None)
        final = [rr.submit("spin", seconds=a.spin) for _ in range(12)]
        final_hosts = Counter(f.result(timeout=a.wait) for f in final)
        phases.append({"rolling": {"programs": len(results), "delivered": sum(1 for r in results if r[3] is None),
                                   "failed": dict(Counter(f"{r[0]}: {r[3]}" for r in results if r[3])),
                                   "seconds": round(rolled, 1),
                                   "per_second": round(len(results) / rolled, 2),
                                   "ran_on": {f"{h}@{rel}": c for (h, rel), c in sorted(ran_on.items(), key=str)},
                                   "by_phase": dict(Counter(r[0] for r in results))}})
        lat = sorted(r[4] for r in results if r[4] is not None)
        q = (lambda p: round(lat[min(len(lat) - 1, int(p * len(lat)))], 2)) if lat else (lambda p: None)
        phases[-1]["rolling"]["latency_s"] = {"median": q(0.5), "p90": q(0.9), "max": q(1.0)}
        phases.append({f"all {to_release}": {"programs": len(final), "delivered": sum(final_hosts.values()),
                                     "ran_on": dict(final_hosts)}})
    finally:
        t.close()
    print(json.dumps({"to": a.to, "logs": str(tmp / "logs"), "robots": a.robots, "gap_s": a.gap, "spin_s": a.spin, "rate_per_s": a.rate,
                      "upgrades": upgrades, "phases": phases}))


if __name__ == "__main__":
    main()
