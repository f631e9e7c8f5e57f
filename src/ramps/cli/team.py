"""``ramps team``: the credentials of a secured team.

    ramps team init --team warehouse        # a team CA in ./ramps-team (ca.key never leaves this machine)
    ramps team add r1                       # r1's bundle in ./ramps-team/r1: ca.pem, cert.pem, key.pem
    ramps team show                         # the CA and every robot issued, with expiry dates
    ramps team revoke r3 --connect tls/192.168.1.11:7447 --credentials ramps-team/admin
                                            # shut r3 out: a signed list the running team adopts

Rules as in ``ramps.cli.common``: user mistakes end with a one-line message and exit
code 2. The work is done by ``ramps.runtime.security``; this module parses and
prints.
"""

from __future__ import annotations

import datetime as _dt
from pathlib import Path
from typing import NoReturn

import typer
from rich.console import Console

from ramps.cli.common import command_group

team_app = command_group("Credentials of a secured team (`ramps node --secure`): a team certificate "
                          "authority and one certificate per robot.")
_out = Console(highlight=False, soft_wrap=True)
_err = Console(stderr=True, highlight=False, soft_wrap=True)

DIR_HELP = "the team's credentials directory (holds the CA)"


def _fail(message: str) -> NoReturn:
    _err.print(f"[bold red]error:[/] {message}")
    raise typer.Exit(2)


@team_app.command("init")
def team_init(
    directory: Path = typer.Option(Path("ramps-team"), "--dir", "-d", help=DIR_HELP),
    team: str = typer.Option("lab", "--team", "-t", help="team name (the nodes' --team)"),
    days: int = typer.Option(3650, "--days", min=1, help="how long the CA is valid"),
    force: bool = typer.Option(False, "--force", help="replace an existing CA (every certificate it issued stops working)"),
) -> None:
    """Create the team's certificate authority: ca.key (secret, mode 0600) and ca.pem."""
    from ramps.errors import CredentialsError
    from ramps.runtime import security

    try:
        security.create_ca(directory, team, days=days, force=force)
    except (CredentialsError, ValueError) as exc:
        _fail(str(exc))
    _out.print(f"team [bold]{team}[/]: certificate authority in {directory}/ ({security.CA_CERT}, "
               f"{security.CA_KEY}). Keep {directory / security.CA_KEY} here, off the robots.")
    _out.print(f"next: ramps team add ROBOT --dir {directory}   (once per robot)")


@team_app.command("add")
def team_add(
    robot: str = typer.Argument(..., help="robot name, as its node's --robot (the certificate's common name)"),
    directory: Path = typer.Option(Path("ramps-team"), "--dir", "-d", help=DIR_HELP),
    host: list[str] | None = typer.Option(None, "--host", help="extra DNS name or IP address of the robot for TLS name checks (repeatable)"),
    days: int = typer.Option(730, "--days", min=1, help="how long the certificate is valid"),
    force: bool = typer.Option(False, "--force", help="issue new credentials even if the robot has some"),
) -> None:
    """Issue ROBOT a key and a certificate signed by the team CA, and say what to copy where."""
    from ramps.errors import CredentialsError
    from ramps.runtime import security

    try:
        out = security.issue(directory, robot, days=days, hosts=host or [], force=force)
        creds = security.check_credentials(out / security.BUNDLE_CA, out / security.BUNDLE_CERT,
                                           out / security.BUNDLE_KEY, robot=robot)
    except (CredentialsError, ValueError) as exc:
        _fail(str(exc))
    _out.print(f"robot [bold]{robot}[/] of team [bold]{creds.team}[/]: credentials in {out}/ "
               f"(valid until {creds.not_after:%Y-%m-%d})")
    _out.print(f"copy these 3 files onto {robot}, e.g. into ~/.ramps-credentials/ (keep key.pem mode 0600):")
    for name in (security.BUNDLE_CA, security.BUNDLE_CERT, security.BUNDLE_KEY):
        _out.print(f"  {out / name}")
    _out.print(f"  e.g.  scp -rp {out} {robot}:.ramps-credentials")
    _out.print(f"then on {robot}: ramps node --robot {robot} --team {creds.team} --secure "
               "--credentials ~/.ramps-credentials --listen tls/0.0.0.0:7447 [--connect tls/TEAMMATE:7447]")


@team_app.command("show")
def team_show(directory: Path = typer.Option(Path("ramps-team"), "--dir", "-d", help=DIR_HELP)) -> None:
    """The team CA and every robot it issued credentials to here, with expiry dates."""
    from ramps.errors import CredentialsError
    from ramps.runtime import security

    try:
        ca, _, team = security.load_ca(directory)
    except CredentialsError as exc:
        _fail(str(exc))
    now = _dt.datetime.now(_dt.UTC)
    _out.print(f"team [bold]{team}[/]: CA {directory / security.CA_CERT}, valid until "
               f"{ca.not_valid_after_utc:%Y-%m-%d}")
    for sub in sorted(p for p in directory.iterdir() if (p / security.BUNDLE_CERT).exists()):
        try:
            c = security.check_credentials(sub / security.BUNDLE_CA, sub / security.BUNDLE_CERT,
                                           sub / security.BUNDLE_KEY, now=now)
            _out.print(f"  {c.robot:16s} valid until {c.not_after:%Y-%m-%d}")
        except CredentialsError as exc:
            _out.print(f"  {sub.name:16s} [red]{exc}[/]")


@team_app.command("revoke")
def team_revoke(
    robots: list[str] = typer.Argument(..., help="robot name(s) to shut out (certificate common names)"),
    directory: Path = typer.Option(Path("ramps-team"), "--dir", "-d", help=DIR_HELP),
    connect: list[str] | None = typer.Option(None, "--connect", "-c", help="a teammate's endpoint to tell the running team through, e.g. tls/192.168.1.11:7447 (repeatable; without it, only the files are written)"),
    credentials: Path | None = typer.Option(None, "--credentials", help="a team bundle to join with when telling the team (e.g. one made by `ramps team add admin`); default: the first bundle in --dir that is not revoked"),
    multicast: bool = typer.Option(False, "--multicast/--no-multicast", help="find the team by multicast scouting"),
    wait: float = typer.Option(10.0, "--wait", min=0.5, help="seconds to wait for a teammate to link when telling the team"),
) -> None:
    """Revoke ROBOT: no teammate accepts anything from it any more, and it may not join.

    Adds ROBOT to the team's revocation list, signed with the CA key, in
    DIR/revoked.json and in every robot bundle under DIR (copy it to robots
    that were offline: `scp ramps-team/revoked.json ROBOT:.ramps-credentials/`).
    With --connect (or --multicast) the running team is told at once: every
    node checks the signature, adopts the list, passes it on to teammates
    that were away, shuts the robot out (its programs are placed elsewhere)
    and a revoked robot's own node leaves the team. A robot that keeps its
    network links and lies about its name is not stopped by this: for a
    compromised robot, restart the nodes with `members` naming the others
    (config file or RAMPS_MEMBERS), or replace the team CA (`ramps team init --force`)."""
    from ramps.errors import CredentialsError
    from ramps.runtime import revocation, security

    try:
        rl, written = revocation.revoke(directory, list(robots))
    except (CredentialsError, ValueError) as exc:
        _fail(str(exc))
    _out.print(f"team [bold]{rl.team}[/]: revocation list {rl.seq} names {', '.join(rl.robots)}; written to "
               f"{', '.join(str(p) for p in written)}")
    if not connect and not multicast:
        _out.print("the running team was not told (no --connect): nodes learn it from these files at start, "
                   "or from any teammate that has it")
        return
    if credentials is None:
        bundles = [sub for sub in sorted(directory.iterdir()) if (sub / security.BUNDLE_CERT).exists()
                   and sub.name not in rl.robots]
        if not bundles:
            _fail(f"no bundle to join the team with in {directory}: make one with `ramps team add admin "
                  f"--dir {directory}`, or pass --credentials")
        credentials = bundles[0]
    try:
        peers, _ = revocation.publish(rl, team=rl.team, connect=list(connect or []), credentials=str(credentials),
                                   multicast=multicast, wait=wait)
    except (CredentialsError, ValueError) as exc:
        _fail(str(exc))
    except Exception as exc:  # Zenoh failing to open: say so plainly
        _fail(f"could not join team {rl.team!r} to tell it: {exc}")
    if not peers:
        _fail(f"no teammate linked within {wait:g} s at {', '.join(connect or ['multicast'])}: the team was not told "
              "(the list files are written; nodes read them at start)")
    _out.print(f"told the running team ({peers} teammate(s) linked); every node passes it on")
