"""``ramps team``: the credentials of a secured team.

    ramps team init --team warehouse        # a team CA in ./ramps-team (ca.key never leaves this machine)
    ramps team add r1                       # r1's bundle in ./ramps-team/r1: ca.pem, cert.pem, key.pem
    ramps team show                         # the CA and every robot issued, with expiry dates

Rules as in ``ramps.cli``: user mistakes end with a one-line message and exit
code 2. The work is done by ``ramps.runtime.security``; this module parses and
prints.
"""

from __future__ import annotations

import datetime as _dt
from pathlib import Path

import typer
from rich.console import Console

team_app = typer.Typer(help="Credentials of a secured team (`ramps node --secure`): a team certificate "
                            "authority and one certificate per robot.", no_args_is_help=True)
_out = Console(highlight=False, soft_wrap=True)
_err = Console(stderr=True, highlight=False, soft_wrap=True)

DIR_HELP = "the team's credentials directory (holds the CA)"


def _fail(message: str) -> None:
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
