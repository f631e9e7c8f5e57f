"""The ``ramps`` command: one module per command group.

    common.py    consoles, ``fail``, checks, JSON output, the shared options (--team, --secure, ...)
    node.py      ramps node | submit | status       (the real team)
    sim.py       ramps sim paper | sweep | campaign | run
    bench.py     ramps bench metrics | sim | dispatch | first-calls | fuzz | flood
    demo.py      ramps demo
    testbed.py   ramps testbed ...                  (the fault commands come from one table, FAULTS)
    team.py      ramps team init | add | show | revoke
    observe.py   ramps report | top
    config.py    ramps config check                 (a node's config file, with the node's own checks)
    ramps.ros.cli  ramps ros                         (rclpy only when it runs)

Rules: the CLI parses, calls the library, prints. User mistakes (a bad
scenario file, an unknown policy) end with a one-line message and exit code
2, never a traceback. Long work shows progress on stderr so ``--json`` output
on stdout stays clean for scripts. A command imports what it drives inside
its function, so ``ramps --help`` stays fast.
"""

from __future__ import annotations

import typer

from ramps import __version__
from ramps.cli.bench import bench_app
from ramps.cli.config import register as _register_config
from ramps.cli.common import command_group, command_help, out
from ramps.cli.demo import demo
from ramps.cli.node import node, status, submit
from ramps.cli.observe import register as _register_observe
from ramps.cli.sim import sim_app
from ramps.cli.team import team_app
from ramps.cli.testbed import testbed_app
from ramps.ros.cli import register as _register_ros

app = command_group(
    "ramps: share computational work across a robot team, with no central scheduler, "
    "and keep it alive when robots fail (Reliable Autonomous Mobile Programs).",
    add_completion=False,
    pretty_exceptions_enable=False,
)
app.add_typer(sim_app, name="sim")
app.add_typer(bench_app, name="bench")
app.add_typer(team_app, name="team")
_register_observe(app)  # ramps report, ramps top
_register_ros(app)  # ramps ros
_register_config(app)  # ramps config check


@app.command()
def version() -> None:
    """Print the ramps version and the wire protocol it speaks (docs/wire-compatibility.md)."""
    from ramps.core.messages import PROTOCOL

    out.print(f"ramps {__version__} (protocol {PROTOCOL})")


def _version_flag(value: bool) -> None:
    if value:
        version()
        raise typer.Exit()


@app.callback()
def _ramps(show_version: bool = typer.Option(False, "--version", callback=_version_flag, is_eager=True,
                                             help="print the ramps version and wire protocol, then exit "
                                                  "(as `ramps version`)")) -> None:
    pass


app.command(help=command_help(node))(node)  # its docstring says why it is long
app.command()(submit)
app.command()(status)
app.command()(demo)
app.command()(__import__("ramps.cli.router", fromlist=["router"]).router)  # ramps router (sites)
app.add_typer(testbed_app, name="testbed")


def main() -> None:
    app()


__all__ = ["app", "main"]
