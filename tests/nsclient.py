"""A client that runs inside a robot's network namespace (``nsenter --net``),
so it keeps talking to that robot's node when the robot's link is cut: the
application on the origin robot itself. Prints one JSON line per program.

    python tests/nsclient.py TEAM ENDPOINT PROGRAM JSON_KWARGS [COUNT [POLICY]]
"""

from __future__ import annotations

import json
import sys

from ramps.runtime.client import Team
from ramps.runtime.settings import load_settings


def main() -> None:
    team_name, endpoint, program, kwargs = sys.argv[1], sys.argv[2], sys.argv[3], json.loads(sys.argv[4])
    count = int(sys.argv[5]) if len(sys.argv) > 5 else 1
    policy = sys.argv[6] if len(sys.argv) > 6 else ""
    s = load_settings(flags={"team": team_name, "connect": [endpoint], "multicast": False, "listen": []},
                      default_robot=False, environ={})
    with Team(s, robot="r1", timeout=30.0) as team:
        opts = team.options(policy=policy) if policy else team
        futures = [opts.submit(program, **kwargs) for _ in range(count)]
        print(json.dumps({"submitted": count}), flush=True)
        for f in futures:
            try:
                value = f.result(timeout=300)
                print(json.dumps({"ok": True, "host": f.host, "attempts": f.attempts, "value": value}), flush=True)
            except Exception as exc:  # reported, the test decides
                print(json.dumps({"ok": False, "error": f"{type(exc).__name__}: {exc}"}), flush=True)


if __name__ == "__main__":
    main()
