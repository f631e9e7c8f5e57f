"""``ramps testbed experiment split``: a Zenoh session split for good, on the testbed.

The work is ``ramps.lab.split``; this module parses and prints (rules in
``ramps.cli.common``).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Optional

import typer

from ramps.cli.common import err, fail, out


def testbed_experiment_split(
    tries: int = typer.Option(3, "--tries", min=1, max=50, help="tries, each on a fresh testbed (a split comes in "
                              "some only: 2 of 5 here)"),
    restart: bool = typer.Option(True, "--restart/--warn-only", help="the nodes' restart_when_split: leave and be "
                                 "restarted (as under systemd) or only warn"),
    watch: float = typer.Option(90.0, "--watch", min=10.0, max=600.0, help="seconds to watch after the cut"),
    out_file: Optional[Path] = typer.Option(None, "--out", help="also save the JSON here"),
) -> None:
    """eclipse-zenoh/zenoh#2806 on two robots: they dial each other, leases of 2 and 20 s,
    their TCP connections black-holed (new ones pass). Prints, per try, which node warned
    that its teammate is heard one way only, which exited and was restarted, and whether
    the team is whole and runs programs afterwards. Root; about 2 minutes a try."""
    from ramps.errors import RampsError
    from ramps.lab.split import run_split

    runs = []
    for i in range(tries):
        def say(message: str, i: int = i) -> None:
            err.print(f"try {i + 1}: {message}", highlight=False, soft_wrap=True)

        try:
            rep = run_split(restart=restart, watch=watch, log=say)
        except (PermissionError, RampsError, RuntimeError, TimeoutError) as exc:
            fail(str(exc))
        runs.append(rep)
        out.print(json.dumps(rep), highlight=False, soft_wrap=True)
    splits = sum(1 for r in runs if r.get("events") or "split" in r)
    out.print(f"{splits} of {tries} tries split; whole at the end in "
              f"{sum(1 for r in runs if 'split' not in r)} of {tries}", highlight=False)
    if out_file is not None:
        out_file.write_text(json.dumps({"runs": runs}, indent=1))


def register(experiment_app: typer.Typer) -> None:
    experiment_app.command("split")(testbed_experiment_split)
