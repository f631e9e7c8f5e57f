"""``ramps config``: a node's configuration, checked before it runs.

    ramps config check /etc/ramps/node.toml                   # ok and the effective settings, or every problem
    ramps config check node.toml --env-file /etc/ramps/node.env   # with the service's environment
    ramps config check node.toml --json                       # the effective settings as JSON
    ramps config reference > docs/configuration.md            # every setting, flag and variable

The checks are the node's own (``ramps.runtime.config_check``); this module
prints. Exit 0 when the node would start with this file, 2 otherwise, one
line per problem on stderr.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Optional

import msgspec
import typer
from rich.markup import escape

from ramps.cli.common import command_group, err, fail, out

config_app = command_group("A node's configuration: check a config file before it runs (ramps node "
                            "--config), or print the reference of every setting.")


@config_app.command("check")
def check(
    file: Path = typer.Argument(..., help="the TOML file `ramps node --config` reads, e.g. /etc/ramps/node.toml"),
    env_file: Optional[Path] = typer.Option(None, "--env-file", help="RAMPS_* variables as the service gets them "
                                            "(systemd EnvironmentFile=, e.g. /etc/ramps/node.env); they override the file"),
    use_environ: bool = typer.Option(False, "--environ", help="also apply the RAMPS_* variables of this shell, "
                                     "as `ramps node` run from it would"),
    robot: Optional[str] = typer.Option(None, "--robot", "-r", help="the robot name the node gets by flag, if any "
                                        "(default: the file's, else this host's name)"),
    as_json: bool = typer.Option(False, "--json", help="print the effective settings as JSON"),
) -> None:
    """Check a node's config file: unknown keys, wrong types, bad values and endpoints,
    secure mode without credentials, programs that do not import. Prints "ok" and the
    effective settings, or one line per problem (exit 2)."""
    import os

    from ramps.errors import ConfigError
    from ramps.runtime.config_check import check_config, read_env_file, summary

    environ: dict[str, str] = {}
    if use_environ:
        environ.update({k: v for k, v in os.environ.items() if k.startswith("RAMPS_")})
    if env_file is not None:
        try:
            environ.update(read_env_file(env_file))
        except OSError as exc:
            fail(f"cannot read environment file {env_file}: {exc.strerror or exc}")
        except ConfigError as exc:
            fail(str(exc))
    result = check_config(file, environ=environ, robot=robot)
    if not result.ok:
        for p in result.problems:
            err.print(f"[bold red]error:[/] {escape(f'{file}: {p}')}", highlight=False, soft_wrap=True)
        raise typer.Exit(2)
    assert result.settings is not None
    if as_json:
        sys.stdout.write(msgspec.json.encode(result.settings).decode() + "\n")
        return
    out.print(f"ok: {file}" + (f" (with {env_file})" if env_file else ""), highlight=False)
    rows = summary(result.settings)
    width = max(len(name) for name, _ in rows)
    for name, value in rows:
        out.print(f"  {name.ljust(width)}  {value}", highlight=False, soft_wrap=True)


@config_app.command("reference")
def reference() -> None:
    """Print the configuration reference as Markdown: every setting of a node with its
    TOML key, `ramps node` flag, environment variable, default and meaning, the
    [commands.NAME], [core] and [zenoh] tables, and the other environment variables
    (docs/configuration.md is this output)."""
    from ramps.cli.reference import reference as make

    sys.stdout.write(make())


def register(app: typer.Typer) -> None:
    """Add ``ramps config`` to the ``ramps`` command."""
    app.add_typer(config_app, name="config")
