"""Running work on the team with the Team API: ``submit`` one program and get
a ``concurrent.futures.Future``, ``map`` over many.

    python examples/submit_and_map.py --local 3        # starts 3 ramps nodes on this machine first
    python examples/submit_and_map.py --team warehouse --robot r1 --connect tcp/192.168.1.11:7447
                                                       # your team: every node runs --program replan:shortest_path

``plan_routes(team)`` is the part you would write in your robot's code.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import Any

import ramps

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))  # replan.py: registering it here lets the client check arguments before sending

import replan  # noqa: E402,F401  (registers shortest_path in this process)

GRID = [
    "..........",
    ".####.###.",
    "....#...#.",
    ".##.###.#.",
    "..........",
]


def calls(n: int) -> list[dict[str, Any]]:
    """``n`` routes across the grid from different starting cells on the top row."""
    return [{"grid": GRID, "start": [0, i % 10], "goal": [4, 9 - i % 10]} for i in range(n)]


def plan_routes(team: Any, n: int = 8, timeout: float = 60.0) -> list[dict]:
    first = team.submit("shortest_path", grid=GRID, start=[0, 0], goal=[4, 9])  # returns at once
    print(f"one route: {first.result(timeout)['length']} steps, computed on {first.host}")
    routes = list(team.map("shortest_path", calls(n), timeout=timeout))  # results, in order
    print(f"{len(routes)} more routes: lengths {[r['length'] for r in routes]}")
    return [first.result()] + routes


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--local", type=int, metavar="N", help="start a team of N nodes on this machine and use it")
    ap.add_argument("--team", help="team name (env RAMPS_TEAM)")
    ap.add_argument("--robot", help="the node to submit through, normally this robot's (default: this host's)")
    ap.add_argument("--connect", action="append", help="Zenoh endpoint of a teammate (repeatable)")
    ap.add_argument("-n", type=int, default=8, help="routes to plan with map (default 8)")
    args = ap.parse_args(argv)
    if args.local:
        from ramps.testing import LocalTeam

        path = os.pathsep.join(p for p in (str(HERE), os.environ.get("PYTHONPATH")) if p)
        with LocalTeam(args.local, cores=2, programs=["replan:shortest_path"],
                       env=dict(os.environ, PYTHONPATH=path)) as local:
            plan_routes(local.client("r1"), args.n)
        return 0
    with ramps.connect(team=args.team, robot=args.robot, connect=args.connect) as team:
        plan_routes(team, args.n)
    return 0


if __name__ == "__main__":
    sys.exit(main())
