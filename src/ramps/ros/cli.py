"""``ramps ros``: the command (rclpy is imported only when it runs)."""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Optional

import typer
import typer.core

ROS_HELP = ("Expose this robot's ramps team to ROS 2 (needs: pip install 'ramps-robotics[ros]').\n\n"
            "Every registered program becomes runnable from ROS as the action /ROBOT/ramps/run "
            "(ramps_interfaces/action/RunProgram: build it once with --build-interfaces), or over topics: "
            "send a goal as JSON on /ROBOT/ramps/goal "
            "(std_msgs/String, e.g. {\"goal_id\": \"g1\", \"program\": \"route_plan\", \"args\": {\"seed\": 3}}), "
            "read feedback (host, state, progress) on /ROBOT/ramps/feedback and the result on /ROBOT/ramps/result; "
            "cancel by sending the goal id on /ROBOT/ramps/cancel (the program is withdrawn from the team); goal "
            "states are on /ROBOT/ramps/status (action_msgs/GoalStatusArray).\n\n"
            "Every robot's load and health go to /diagnostics (diagnostic_msgs/DiagnosticArray).\n\n"
            "The options are ROS parameters too: --ros-args -p team:=warehouse -p connect:=\"['tcp/10.0.0.2:7447']\" "
            "-r __ns:=/r1; everything from --ros-args on is ROS's. Where neither gives one, team, connect, multicast, "
            "secure and credentials come from the environment (RAMPS_TEAM, RAMPS_CONNECT, ...) and RAMPS_CONFIG, as "
            "for every ramps command. See docs/ros2.md.")


class _RosArgsCommand(typer.core.TyperCommand):
    """``ramps ros``'s parsing: everything from ``--ros-args`` on goes to ROS
    untouched (rcl's own ``-r``, ``-p``, ``-e`` are not ramps' ``-r``...);
    before it, ramps' options only, so a typo is an error, not a ROS argument."""

    def parse_args(self, ctx, args: list[str]) -> list[str]:
        cut = args.index("--ros-args") if "--ros-args" in args else len(args)
        super().parse_args(ctx, args[:cut])
        if ctx.args:  # (the command takes unknown words only to hand them to ROS: not these)
            ctx.fail(f"no such option or argument: {' '.join(ctx.args)} (ROS arguments go after --ros-args)")
        ctx.args = args[cut:]
        return ctx.args


def register(app: typer.Typer) -> None:
    @app.command(cls=_RosArgsCommand, context_settings={"allow_extra_args": True, "ignore_unknown_options": True},
                 help=ROS_HELP)
    def ros(
        ctx: typer.Context,
        team: Optional[str] = typer.Option(None, "--team", "-t", help="team name (parameter team; default: "
                                           "RAMPS_TEAM, else lab)"),
        robot: Optional[str] = typer.Option(None, "--robot", "-r", help="the ramps node to submit to, normally this "
                                            "robot's (parameter robot; default: the one named after this host)"),
        connect: Optional[list[str]] = typer.Option(None, "--connect", "-c", help="Zenoh endpoint of the team "
                                                    "(repeatable; parameter connect)"),
        multicast: Optional[bool] = typer.Option(None, "--multicast/--no-multicast", help="find the team by UDP multicast"),
        secure: bool = typer.Option(False, "--secure", help="secured team (parameter secure)"),
        credentials: Optional[Path] = typer.Option(None, "--credentials", help="credentials directory (parameter credentials)"),
        diagnostics_period: Optional[float] = typer.Option(None, "--diagnostics-period", min=0.05,
                                                           help="seconds between /diagnostics messages (default 1)"),
        goal_timeout: Optional[float] = typer.Option(None, "--goal-timeout", min=0.0, help="seconds a goal may run "
                                                     "before its program is withdrawn, unless the goal says (parameter "
                                                     "goal_timeout; default 0: none)"),
        connect_timeout: Optional[float] = typer.Option(None, "--connect-timeout", min=0.05, help="seconds to find "
                                                        "the ramps node at start (parameter connect_timeout; "
                                                        "default 10)"),
        origin_grace: Optional[float] = typer.Option(None, "--origin-grace", min=0.0, help="seconds goals wait for "
                                                     "the ramps node to come back (a restart) before they fail as "
                                                     "lost (parameter origin_grace; default 30)"),
        namespace: Optional[str] = typer.Option(None, "--namespace", help="ROS namespace of the face (default: /<robot>)"),
        build_interfaces: bool = typer.Option(False, "--build-interfaces", help="build the RunProgram action type "
                                              "(ramps_interfaces) into this environment and exit; then ramps ros "
                                              "also serves /ROBOT/ramps/run as a ROS 2 action (needs cmake and a "
                                              "C/C++ compiler; about 20 s of CPU: 82 s on a 2-core machine at "
                                              "load average 50, docs/ros2.md)"),
    ) -> None:
        from ramps.ros import missing

        if build_interfaces:
            from ramps.ros.build import BuildError, build

            try:
                build(log=lambda m: typer.echo(m, err=True))
            except BuildError as exc:
                typer.echo(f"ramps ros --build-interfaces: {exc}", err=True)
                raise typer.Exit(2)
            return

        why = missing()
        if why is not None:
            typer.echo(f"ramps ros: {why}", err=True)
            raise typer.Exit(2)
        from ramps.errors import RampsError
        from ramps.ros.face import ros_name, run

        overrides = {k: v for k, v in {
            "team": team, "robot": robot, "connect": list(connect) if connect else None, "multicast": multicast,
            "secure": True if secure else None, "credentials": str(credentials) if credentials else None,
            "diagnostics_period": diagnostics_period, "goal_timeout": goal_timeout,
            "connect_timeout": connect_timeout, "origin_grace": origin_grace}.items() if v is not None}
        ns = namespace if namespace is not None else ("/" + ros_name(robot) if robot else "")
        try:
            run(namespace=ns, overrides=overrides, ros_args=list(ctx.args))
        except (RampsError, ValueError) as exc:
            typer.echo(f"ramps ros: {exc}", err=True)
            raise typer.Exit(2)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(0)
