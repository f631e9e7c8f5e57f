"""``ramps testbed experiment sites``: two sites behind two routers on the testbed.

The work is ``ramps.lab.sites``; this module parses and prints (rules in
``ramps.cli.common``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from ramps.cli.common import emit, err, fail


def testbed_experiment_sites(
    per_site: int = typer.Option(4, "--robots", min=1, max=20, help="robots per site (r1.. in site A, the rest in B)"),
    mode: str = typer.Option("peer", "--mode", help="the robots' Zenoh mode: peer (site mates linked directly, "
                             "each robot also connects to its router) or client (each robot linked to its router only)"),
    rate: float = typer.Option(250.0, "--rate", min=1.0, max=100_000.0, help="kB/s of the link between the two "
                               "routers, each way (tc tbf; this kernel has no netem, so no added delay)"),
    payload: int = typer.Option(1_000_000, "--payload", min=1, max=8_000_000, help="bytes of parameters of each "
                                "program of the large-parameter batch"),
    outage: float = typer.Option(8.0, "--outage", min=0.0, max=120.0, help="seconds router A stays dead "
                                 "(0: no router crash)"),
    same_site: bool = typer.Option(True, "--same-site/--no-same-site", help="also run the programs on one site "
                                   "of the same robots, no routers, for comparison"),
    as_json: bool = typer.Option(False, "--json", help="write the report as JSON to stdout"),
    out_file: Optional[Path] = typer.Option(None, "--out", help="also save the JSON here"),
) -> None:
    """Two sites of robots on separate networks (two bridges) that reach each other only
    through two routers (`ramps router`, each in its own namespace, their link slowed with
    tc tbf): one team. r1 (site A) measures its links, then places programs with large
    parameters (they stay in site A) and CPU-heavy programs with small parameters (they spill
    over to site B), printed beside the same programs on one site. Then router A is killed
    while r1 and the first robot of site B submit, and started again: both sites keep running
    their programs while apart, none is lost, and the team heals. Root; about 5 minutes."""
    from ramps.errors import RampsError
    from ramps.lab.sites import run_sites
    from ramps.lab.sites_report import format_report

    if mode not in ("peer", "client"):
        fail(f"unknown mode {mode!r}; choose peer or client")
    try:
        rep = run_sites(per_site=per_site, mode=mode, rate=rate * 1e3, large=(2 * per_site, payload, 0.05),
                        cpu=(4 * per_site, 100, 1.0), outage=outage, same_site=same_site,
                        log=lambda m: err.print(m, highlight=False, soft_wrap=True))
    except (PermissionError, RampsError, RuntimeError, TimeoutError) as exc:
        fail(str(exc))
    emit([rep], lambda r, console: console.print(format_report(r), highlight=False, soft_wrap=True),
         as_json=as_json, out_file=out_file)


def register(experiment_app: typer.Typer) -> None:
    experiment_app.command("sites")(testbed_experiment_sites)
