"""Evaluate every query of ramps-team.json on a real Prometheus scraping a real team.

Run from the repository root, with the `prometheus` binary on PATH (Debian: `apt-get install
prometheus`):

    .venv/bin/python docs/grafana/check-with-prometheus.py

It starts Prometheus (scraping every second, data in a temporary directory), a team of three
`ramps node` processes on loopback (tests/runtime_team.py) of which r1 and r2 serve metrics,
runs programs from r1, SIGKILLs r3 under two of them, waits 20 s, then evaluates each panel's
expressions (with $robot = .*) through Prometheus' HTTP API and prints what each returned.
Exit code 1 if Prometheus rejected a query or one returned nothing.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.parse
import urllib.request
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests"))

from runtime_team import LocalTeam  # noqa: E402

from ramps.runtime.localteam import free_port  # noqa: E402


def main() -> int:
    dash = json.loads((ROOT / "docs" / "grafana" / "ramps-team.json").read_text())
    tmp = Path(tempfile.mkdtemp(prefix="ramps-promcheck-"))
    ports = {"r1": free_port(), "r2": free_port()}
    web = free_port()
    (tmp / "prometheus.yml").write_text(
        "global:\n  scrape_interval: 1s\nscrape_configs:\n  - job_name: ramps\n    static_configs:\n"
        f"      - targets: [{', '.join(repr(f'127.0.0.1:{p}') for p in ports.values())}]\n".replace("'", '"'))
    prom = subprocess.Popen(["prometheus", f"--config.file={tmp / 'prometheus.yml'}",
                             f"--storage.tsdb.path={tmp / 'data'}", f"--web.listen-address=127.0.0.1:{web}"],
                            stdout=open(tmp / "prometheus.log", "w"), stderr=subprocess.STDOUT)
    t = LocalTeam(3, tmp / "team")
    failures = 0
    try:
        for name in ("r1", "r2", "r3"):
            extra = ["--metrics", f"127.0.0.1:{ports[name]}"] if name in ports else []
            t.start_node(name, wait=False, extra_args=extra)
        t.wait_visible(["r1", "r2", "r3"])
        team = t.client("r1")
        rr = team.options(policy="round_robin")
        futs = [rr.submit("sleepy", seconds=3.0, tag=f"p{i}") for i in range(6)]
        futs += [team.submit("spin", seconds=0.3) for _ in range(4)]
        time.sleep(1.5)
        t.kill_node("r3")
        for f in futs:
            f.result(60)
        time.sleep(20)
        for panel in dash["panels"]:
            for target in panel["targets"]:
                expr = target["expr"].replace("$robot", ".*")
                url = f"http://127.0.0.1:{web}/api/v1/query?" + urllib.parse.urlencode({"query": expr})
                try:
                    res = json.load(urllib.request.urlopen(url, timeout=10))["data"]["result"]
                except urllib.error.HTTPError as exc:
                    failures += 1
                    print(f"REJECTED {panel['title']}: {expr}: {exc.read()[:200]!r}")
                    continue
                failures += not res
                print(f"{'ok   ' if res else 'EMPTY'} {panel['title'][:44]:44} {len(res)} series, e.g. "
                      f"{[r['value'][1] for r in res][:3]}")
    finally:
        t.close()
        prom.terminate()
        prom.wait(10)
        shutil.rmtree(tmp, ignore_errors=True)
    print("every query returned data" if not failures else f"{failures} queries rejected or empty")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
