"""``ramps router``: a Zenoh router that joins the robots of two or more sites into one team.

    ramps router                                          # this site's router on tcp/0.0.0.0:7447
    ramps router --connect tcp/10.0.2.1:7447              # ... linked to the other site's router
    ramps router --secure --credentials ramps-team/router-a --listen tls/0.0.0.0:7447

Rules as in ``ramps.cli.common``: the CLI parses, ``ramps.runtime.router``
does the work, user mistakes end with a one-line message and exit code 2.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from ramps.cli.common import CredentialsOption, SecureOption, TeamOption, err, fail, node_settings

MODE_HELP = ("Zenoh mode: peer (default) links straight to every teammate it finds, for robots of one "
             "network; client links only to a router (--connect tcp/ROUTER:7447) and reaches the team "
             "through it, for robots that cannot reach each other or a client of a site behind routers; "
             "see `ramps router --help` (env RAMPS_MODE)")
ZENOH_HELP = ("raw Zenoh setting KEY=VALUE applied last, e.g. transport/link/tx/batch_size=8192 (repeatable; "
              "[zenoh] table in --config); ramps's own keys and, when secured, TLS and access control are refused")
#: ``--mode`` of ``ramps node``, ``submit`` and ``status``
ModeOption = Annotated[Optional[str], typer.Option("--mode", help=MODE_HELP)]
#: ``--zenoh`` of ``ramps node`` and ``ramps router``
ZenohOption = Annotated[Optional[list[str]], typer.Option("--zenoh", help=ZENOH_HELP)]


def zenoh_flags(items: Optional[list[str]]) -> Optional[dict]:
    """``--zenoh`` items as the ``zenoh`` setting (None when none), or a clear exit."""
    from ramps.errors import ConfigError
    from ramps.runtime.settings import parse_zenoh_overrides

    if not items:
        return None
    try:
        return parse_zenoh_overrides(items)
    except ConfigError as exc:
        fail(str(exc))


ROUTER_HELP = """Run a Zenoh router until Ctrl-C: it joins robots on separate networks into one team.

Each site (a network the robots share: a hall, a depot, a yard) runs one router;
its robots connect to it (`ramps node --connect tcp/ROUTER:7447`), and the routers
connect to each other (`ramps router --connect tcp/OTHER-ROUTER:7447`). Programs
then go wherever the team's cost model sends them, across sites too, priced by the
link each robot measures.

Robots of a site in peer mode (the default) also link to each other directly: if
their router dies, the site keeps working on its own and joins the other sites
again when the router is back. In client mode (`ramps node --mode client`) a robot
links only to its router: use it where robots cannot reach each other (WiFi with
client isolation) or are too many to link pairwise.

A router runs no programs and keeps no state: restart it at will. The team name
matters only on a secured team (--secure: TLS with a team certificate from
`ramps team add ROUTER-NAME`, and the team's access control). See
docs/sites-and-routers.md.
"""


def router(
    team: TeamOption = None,
    listen: Optional[list[str]] = typer.Option(None, "--listen", "-l",
                                               help="endpoint to listen on for robots and other routers "
                                                    "(repeatable; default tcp/0.0.0.0:7447, tls/... when --secure)"),
    connect: Optional[list[str]] = typer.Option(None, "--connect", "-c",
                                                help="another site's router, e.g. tcp/10.0.2.1:7447 (repeatable; "
                                                     "it is dialled again whenever the link drops; env RAMPS_CONNECT)"),
    multicast: Optional[bool] = typer.Option(None, "--multicast/--no-multicast",
                                             help="answer multicast scouting, so robots on this network find the "
                                                  "router without --connect (default on)"),
    config_file: Optional[Path] = typer.Option(None, "--config", help="TOML config file, the nodes' format "
                                               "(team, listen, connect, lease_ms, secure, credentials, [zenoh]; "
                                               "env RAMPS_CONFIG)"),
    lease_ms: Optional[int] = typer.Option(None, "--lease-ms", help="Zenoh lease: how fast a dead link is noticed "
                                           "(default 2000, as the nodes)"),
    zenoh: ZenohOption = None,
    secure: SecureOption = False,
    credentials: CredentialsOption = None,
) -> None:
    import signal
    import threading

    from ramps.errors import RampsError
    from ramps.runtime.router import Router

    overrides = zenoh_flags(zenoh)
    s = node_settings(team=team, listen=listen or None, connect=connect or None, multicast=multicast,
                      config_file=config_file, lease_ms=lease_ms, secure=secure or None,
                      credentials=str(credentials) if credentials else None, zenoh=overrides,
                      default_robot=False)
    stop = threading.Event()
    old = {sig: signal.signal(sig, lambda *_: stop.set()) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        try:
            r = Router.open(s)
        except RampsError as exc:
            fail(str(exc))
        with r:
            who = f" as {r.credentials.robot} of team {s.team}: TLS with team certificates" if r.credentials else ""
            err.print(f"[bold]ramps router[/] {r.zid[:8]} listening on {', '.join(r.listening)}"
                      + (f"; linking to {', '.join(s.connect)}" if s.connect else "")
                      + ("; answers multicast scouting" if s.multicast else "") + who
                      + ". Ctrl-C to stop.", highlight=False, soft_wrap=True)
            seen = None
            while not stop.wait(1.0):
                links = r.links()
                now = (len(links.routers), len(links.peers))
                if now != seen:
                    err.print(f"linked to {now[0]} other router(s) and {now[1]} robot(s) in peer mode "
                              "(robots in client mode are not counted)", highlight=False, soft_wrap=True)
                    seen = now
        err.print("ramps router: stopped", highlight=False)
    finally:
        for sig, prev in old.items():
            signal.signal(sig, prev)


# one line per paragraph: the help's renderer wraps them to the terminal
router.__doc__ = "\n\n".join(" ".join(p.split()) for p in ROUTER_HELP.split("\n\n"))
