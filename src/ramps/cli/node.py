"""``ramps node``, ``ramps submit``, ``ramps status``: the real team.

    ramps node --robot r1                      # this robot's node until Ctrl-C
    ramps submit route_plan --arg seed=3       # run a program on the team, print its result
    ramps status                               # the team's robots, load and programs

This module parses and prints (rules in ``ramps.cli.common``); the node is
``ramps.runtime.node``, the client ``ramps.runtime.client``.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import Any, Optional

import msgspec
import typer

from ramps.cli.router import ModeOption, ZenohOption, zenoh_flags
from ramps.cli.common import (
    ConnectOption,
    CredentialsOption,
    FindTeamOption,
    PolicyOption,
    SecureOption,
    TeamOption,
    check_policy,
    err,
    fail,
    node_settings,
    out,
)

#: the exit code of a node that left to be restarted (``restart_when_split``): EX_TEMPFAIL
SPLIT_EXIT = 75


def node(
    robot: Optional[str] = typer.Option(None, "--robot", "-r", help="this robot's name (default: host name; env RAMPS_ROBOT)"),
    team: TeamOption = None,
    listen: Optional[list[str]] = typer.Option(None, "--listen", "-l", help="Zenoh endpoint to listen on (repeatable; default tcp/0.0.0.0:0)"),
    connect: ConnectOption = None,
    multicast: Optional[bool] = typer.Option(None, "--multicast/--no-multicast", help="find teammates by UDP multicast (default on)"),
    cores: Optional[int] = typer.Option(None, "--cores", min=1, help="cores offered to programs (default: detected)"),
    speed: Optional[float] = typer.Option(None, "--speed", help="work units per second per core (default: measured)"),
    accelerator: Optional[list[str]] = typer.Option(
        None, "--accelerator", metavar="KIND[:COUNT[:SPEED]]",
        help="an accelerator this robot offers to programs that can use one (repeatable; env RAMPS_ACCELERATORS): "
             "cuda:1:20 is one slot of 20 work units a second; 'auto' (the default) finds NVIDIA GPUs (needs the "
             "nvidia-ml-py package) and offers them as cuda; 'none' offers nothing; KIND:COUNT:SPEED:emulated "
             "stands slot locks in for a device (a testbed's)"),
    policy: PolicyOption = None,
    program: Optional[list[str]] = typer.Option(None, "--program", help="extra program as package.module:function (repeatable)"),
    command: Optional[list[str]] = typer.Option(None, "--command", help="an executable as a program, NAME=PATH (repeatable; env RAMPS_COMMANDS): "
                                                "it gets the call's arguments as a JSON object on stdin and prints its result as JSON "
                                                "on stdout; a non-zero exit is a failure (the tail of its stderr goes to the caller); "
                                                "'RAMPS_PROGRESS 0.4' lines on stderr report progress; its process group is killed when "
                                                "the program is withdrawn or after 600 s (another limit: timeout in a [commands.NAME] "
                                                "table of --config)"),
    config_file: Optional[Path] = typer.Option(None, "--config", help="TOML config file (env RAMPS_CONFIG)"),
    lease_ms: Optional[int] = typer.Option(None, "--lease-ms", help="Zenoh session lease: how fast a frozen or cut-off peer is noticed"),
    node_nice: Optional[int] = typer.Option(None, "--node-nice", min=-20, max=19,
                                            help="niceness of this node's process, above its programs' (default -5; "
                                                 "below 0 needs root, else it stays as it is; env RAMPS_NODE_NICE)"),
    trace: Optional[Path] = typer.Option(None, "--trace", help="write every placement, failure and delivery decision to this file (JSON lines)"),
    secure: SecureOption = False,
    credentials: CredentialsOption = None,
    mode: ModeOption = None,
    zenoh: ZenohOption = None,
    metrics: Optional[str] = typer.Option(None, "--metrics", help="serve Prometheus metrics on ADDR:PORT, e.g. "
                                          "127.0.0.1:9464 or 0.0.0.0:9464 for a Prometheus elsewhere (default off; "
                                          "env RAMPS_METRICS)"),
    state_dir: Optional[str] = typer.Option(None, "--state-dir", help="keep this robot's durable record of the "
                                            "programs it submitted here, so a restarted node resumes them "
                                            "(default: $STATE_DIRECTORY, else ~/.local/state/ramps; 'off': none; "
                                            "env RAMPS_STATE_DIR)"),
    battery_file: Optional[str] = typer.Option(
        None, "--battery-file", metavar="PATH",
        help="a file holding this robot's battery charge, a percentage (87) or a fraction (0.87), read before "
             "each load report; {robot} becomes the robot's name (env RAMPS_BATTERY_FILE). Below its reserve "
             "([core] battery_reserve, default 0.2) a robot takes no teammates' programs and hands back those "
             "it runs; its own still run. Without --battery-file or --battery-command, Linux's battery "
             "(/sys/class/power_supply) is read where the kernel has one"),
    battery_command: Optional[str] = typer.Option(
        None, "--battery-command", metavar="CMD",
        help="instead, a shell command that prints the charge the same way (87% or 0.87), run at most once a "
             "report period and killed after 5 s (env RAMPS_BATTERY_COMMAND)"),
    battery_sysfs: Optional[bool] = typer.Option(
        None, "--battery-sysfs/--no-battery-sysfs",
        help="without a file or a command, read Linux's battery where the kernel lists one (default on; env "
             "RAMPS_BATTERY_SYSFS); off for robots emulated on one machine, which would share its battery"),
    power_per_core: Optional[str] = typer.Option(
        None, "--power-per-core", metavar="WATTS",
        help="watts one busy core of this robot draws, or 'rapl' to measure them (Intel RAPL), for placement "
             "that weighs energy ([core] energy_weight; default: not known)"),
    verbose: bool = typer.Option(False, "--verbose", "-v", help="log every blacklisting and failure"),
) -> None:
    """Run this robot's ramps node until Ctrl-C: load publisher, load server, program executor.

    Long because of its 26 options: typer reads each from a parameter of this function.

    On shutdown (Ctrl-C, SIGTERM) running programs are handed back to their origins, which
    place them elsewhere at once. Programs submitted to this node are kept in its durable
    record (--state-dir): a node restarted, after a crash or a stop, resumes them, and
    their clients receive their outcomes, each exactly once.
    """
    import logging

    from rich.logging import RichHandler

    from ramps.errors import RampsError
    from ramps.runtime.node import NodeRuntime, prioritize
    from ramps.runtime.service import Service

    logging.basicConfig(level=logging.INFO if verbose else logging.WARNING, format="%(message)s",
                        handlers=[RichHandler(console=err, show_path=False)])
    if policy is not None:
        check_policy(policy)
    commands = None
    if command:
        from ramps.errors import ConfigError
        from ramps.runtime.settings import parse_commands

        try:
            commands = {k: msgspec.to_builtins(v) for k, v in parse_commands(command).items()}
        except (ConfigError, ValueError) as exc:
            fail(str(exc))
    s = node_settings(robot=robot, commands=commands, team=team, listen=listen or None, connect=connect or None, multicast=multicast,
                  cores=cores, speed=speed, accelerators=accelerator or None, policy=policy, programs=program or None,
                  config_file=config_file,
                  lease_ms=lease_ms, trace=str(trace) if trace else None, secure=secure or None,
                  credentials=str(credentials) if credentials else None, metrics=metrics, node_nice=node_nice,
                  state_dir=state_dir, mode=mode, zenoh=zenoh_flags(zenoh), battery_file=battery_file,
                  battery_command=battery_command, battery_sysfs=battery_sysfs,
                  power_per_core=_watts(power_per_core))
    if not s.state_dir:
        from ramps.runtime.store import default_state_dir

        s = msgspec.structs.replace(s, state_dir=str(default_state_dir()))
    import signal
    import threading

    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    prioritize(s.node_nice)  # before the node starts its threads and workers: they inherit it
    service = Service.from_environ()  # under systemd (Type=notify): readiness, status, watchdog
    try:
        rt = NodeRuntime(s).start()
    except RampsError as exc:
        fail(str(exc))
    served = rt.metrics.address if rt.metrics is not None else None
    err.print(f"[bold]ramps node {rt.robot}[/] joined team [bold]{rt.team}[/]: {rt.cores} cores, speed {rt.speed:g}, "
              f"policy {s.policy}, load measured on the {rt.load_scope}; "
              + ("client of a router" if s.mode == "client"
                 else f"listening on {', '.join(rt.endpoints() or s.listen_endpoints())}")
              + (f"; connecting to {', '.join(s.connect)}" if s.connect else "")
              + ("; multicast discovery on" if s.multicast else "")
              + ("; secured: TLS with team certificates" if s.secure else "")
              + (f"; metrics on http://{served[0]}:{served[1]}/metrics" if served else ""),
              highlight=False, soft_wrap=True)
    err.print(f"programs: {', '.join(sorted(rt.registry.names()))}. Ctrl-C to leave the team.", highlight=False,
              soft_wrap=True)
    service.ready(f"robot {rt.robot} in team {rt.team}: {rt.cores} cores, speed {rt.speed:g}")
    service.attach(rt)  # the watchdog is fed by the driver loop from now on
    try:
        while not stop.wait(0.5) and not rt.wait(0):
            pass
    finally:
        service.stopping(f"robot {rt.robot} leaving team {rt.team}: handing running programs back")
        err.print(f"ramps node {rt.robot}: leaving the team, handing running programs back ...")
        rt.stop()
        service.close()
    if rt.name_taken:
        fail(f"this node left the team: {rt.name_taken}")
    if rt.split:  # EX_TEMPFAIL: the supervisor starts it again, which heals the split (restart_when_split)
        fail(f"this node left the team to be restarted: {rt.split}", code=SPLIT_EXIT)
    if rt.revoked_self:
        fail(f"robot {rt.robot} was revoked by team {rt.team} (revocation list {rt.revocations.seq if rt.revocations else '?'}): it left the team")


def _watts(text: str | None) -> float | str | None:
    """``--power-per-core``: a number of watts, or ``rapl``."""
    if text is None or text == "rapl":
        return text
    try:
        return float(text)
    except ValueError:
        fail(f"--power-per-core takes watts (a number) or 'rapl', got {text!r}")


def _parse_arg(text: str) -> tuple[str, object]:
    key, sep, raw = text.partition("=")
    if not sep or not key.isidentifier():
        fail(f"--arg must look like name=value, got {text!r}")
    try:
        return key, json.loads(raw)
    except json.JSONDecodeError:
        return key, raw


def _connect_team(team, robot, connect, multicast, timeout, config_file=None, secure=None, credentials=None,
                  mode=None, submits=True):
    from ramps.errors import RampsError
    from ramps.runtime.client import Team

    s = node_settings(team=team, connect=connect or None, multicast=multicast, config_file=config_file,
                  default_robot=False, secure=secure or None, credentials=str(credentials) if credentials else None,
                  mode=mode)
    try:
        return Team(s, robot=robot, timeout=timeout, submits=submits)
    except RampsError as exc:
        fail(str(exc))


def submit(
    program: str = typer.Argument(..., help="registered program name, e.g. route_plan, burn, echo"),
    arg: Optional[list[str]] = typer.Option(None, "--arg", "-a", help="argument name=value (JSON values: 3, 2.5, true, [1,2]); repeatable"),
    team: TeamOption = None,
    robot: Optional[str] = typer.Option(None, "--robot", "-r", help="node that is the origin (default: this host's, or any)"),
    connect: ConnectOption = None,
    multicast: FindTeamOption = None,
    count: int = typer.Option(1, "--count", "-n", min=1, help="submit the same call this many times"),
    timeout: Optional[float] = typer.Option(None, "--timeout", help="give up (and withdraw the program) after this many seconds"),
    as_json: bool = typer.Option(False, "--json", help="print results as JSON lines"),
    progress: bool = typer.Option(False, "--progress", help="print each program's placement, host and progress "
                                  "on stderr as it changes"),
    secure: SecureOption = False,
    credentials: CredentialsOption = None,
    mode: ModeOption = None,
) -> None:
    """Run a program on the team and print its result.

    Each result goes to stdout (with --json, one line per program:
    ok, value or error, state, host, attempts); each error to stderr. The
    last line on stderr says how the programs ended, on which robots they
    ran, and their origin (the node they were submitted to): "2 program(s)
    in 0.41 s, origin r1: 1 done on r2, 1 failed on r3". The exit status is
    2 if a program was refused for its name or arguments (by this command or
    by the node), else 1 if any did not end done."""
    import time as _time

    from ramps.errors import BadArguments, ProgramNotFound, RampsError

    args = dict(_parse_arg(a) for a in arg or [])
    t = _connect_team(team, robot, connect, multicast, 5.0, secure=secure, credentials=credentials, mode=mode)
    try:
        started = _time.perf_counter()
        try:
            futs = [t.options(timeout=timeout).submit(program, **args) for _ in range(count)]
            if progress:
                for i, f in enumerate(futs):
                    f.add_update_callback(lambda f, i=i: None if f.done() else err.print(
                        f"[{i + 1}/{count}] {f.program}: {f.state} on {f.host or '?'}"
                        + ("" if f.progress is None else f" {100 * f.progress:.0f}% {f.progress_detail}"),
                        markup=False, highlight=False, soft_wrap=True))
        except RampsError as exc:
            fail(str(exc))
        code = 0
        for f in futs:
            try:
                value = f.result()
                line = {"ok": True, "value": value}
            except (RampsError, TimeoutError) as exc:
                # refused for its arguments by the node: the caller's mistake, as when caught here (2)
                code = max(code, 2 if isinstance(exc, (BadArguments, ProgramNotFound)) else 1)
                line = {"ok": False, "error": f"{type(exc).__name__}: {exc}"}
            line.update(state=f.state, host=f.host, attempts=f.attempts)
            if as_json:
                sys.stdout.write(json.dumps(line, default=str) + "\n")
            elif line["ok"]:  # results and errors are text, not markup: "list[str]", "grid[0]"
                out.print(line["value"], markup=False)
            else:
                err.print(line["error"], style="red", markup=False, highlight=False, soft_wrap=True)
        if not as_json:
            err.print(how_they_ended(futs, t.robot, _time.perf_counter() - started), highlight=False, soft_wrap=True)
    finally:
        t.close()
    raise typer.Exit(code)



_ENDINGS = ("done", "failed", "timed_out", "cancelled")


def how_they_ended(futs: list, origin: str, seconds: float) -> str:
    """``ramps submit``'s last line: how many programs ended how and on which
    robots ("3 done on r2 (2), r3"; none for a program never placed), and
    the origin they were submitted to."""
    ends: dict[str, dict[str, int]] = {}
    for f in futs:
        hosts = ends.setdefault(f.state, {})
        hosts[f.host] = hosts.get(f.host, 0) + 1
    parts = []
    for state in sorted(ends, key=lambda s: (_ENDINGS.index(s) if s in _ENDINGS else len(_ENDINGS), s)):
        hosts = ends[state]
        where = ", ".join(h + (f" ({n})" if n > 1 else "") for h, n in sorted(hosts.items()) if h)
        parts.append(f"{sum(hosts.values())} {state.replace('_', ' ')}" + (f" on {where}" if where else ""))
    return f"{len(futs)} program(s) in {seconds:.2f} s, origin {origin}: {', '.join(parts)}"


def _heard_all(t, wait: float):
    """The team's status once every robot alive has published a load report
    (reports come once a second), or after ``wait`` seconds."""
    import time as _time

    deadline = _time.monotonic() + wait
    _time.sleep(min(wait, 0.2))  # the team's liveliness tokens come first, all at once
    while True:
        st = t.status()
        if _time.monotonic() >= deadline or (st.robots and all(r.report_age is not None for r in st.robots if r.alive)):
            return st
        _time.sleep(0.05)


def status(
    team: TeamOption = None,
    connect: ConnectOption = None,
    multicast: FindTeamOption = None,
    wait: float = typer.Option(2.5, "--wait", help="seconds to listen for load reports at most: the table comes as "
                               "soon as every robot alive has reported"),
    secure: SecureOption = False,
    credentials: CredentialsOption = None,
    as_json: bool = typer.Option(False, "--json", help="print the team view as JSON"),
    mode: ModeOption = None,
) -> None:
    """Show the team: robots, their load, running programs, blacklisted peers, the links
    each robot measured to its teammates and the work it learned of its programs.

    "moved" counts the robot's own programs that it relocated while they ran
    (a teammate became busy, or a better one appeared), and the moves it
    abandoned because the new host refused or failed. "node cores" is what
    the robot's node itself uses (averaged over about 10 s); when programs
    fill the robot, placements count them as cores the programs cannot have.

    Each row is what that robot last published. "sees" is how many teammates
    the robot itself could place a program on (fresh report, not written
    off; on a robot no application submits to, the teammates it holds
    alive): a robot that sees fewer than the rest is cut off from part of
    the team, even when this command sees everyone."""

    from rich.table import Table

    t = _connect_team(team, None, connect, multicast, 5.0, secure=secure, credentials=credentials, mode=mode,
                      submits=False)
    try:
        st = _heard_all(t, wait)
    finally:
        t.close()
    if as_json:
        sys.stdout.write(msgspec.json.encode(st).decode() + "\n")
        return
    table = Table(title=f"team {st.team}", title_justify="left")
    for name in ("robot", "alive", "cores", "speed", "cpu busy", "per core %", "run queue", "load avg", "mem free",
                 "programs", "done", "moved", "node cores", "dropped msgs", "sees", "blacklists", "report age"):
        table.add_column(name, justify="left" if name in ("robot", "blacklists", "per core %") else "right")
    for r in st.robots:
        alive = "yes" if r.alive else "no (left)" if r.leaving else "[red]no[/]"  # left: stopped, not crashed
        table.add_row(r.robot, alive, str(r.cores), f"{r.speed:g}", f"{r.cpu_busy:.2f}",
                      " ".join(f"{100 * c:.0f}" for c in r.cpu_per_core[:16]), f"{r.runnable:.1f}",
                      f"{r.load_avg:.2f}", f"{r.mem_free / 2**30:.1f} GiB", str(r.ramps_running),
                      str(r.finished_total),
                      str(r.moves) + (f" ({r.moves_aborted} abandoned)" if r.moves_aborted else ""),
                      f"{r.node_cpu:.2f}",
                      str(r.bad_messages), "-" if r.sees is None else str(r.sees),
                      ", ".join(r.blacklisted),
                      "-" if r.report_age is None else f"{r.report_age:.1f} s")
    out.print(table)
    _print_accelerators(st)
    _print_batteries(st)
    links = [(r.robot, link) for r in st.robots for link in r.links]
    if links:  # T_comm as each robot measured it (ramps.core.links): the cost model prices transfers with these
        lt = Table(title="links each robot measured, and teammates' speeds its results corrected "
                         "(its placements use them)", title_justify="left")
        for name in ("robot", "to", "latency", "bandwidth", "speed x"):
            lt.add_column(name, justify="left" if name in ("robot", "to") else "right")
        for robot, link in links:
            lt.add_row(robot, link.robot, "-" if link.latency is None else f"{1000 * link.latency:.1f} ms",
                       "-" if link.bandwidth is None else f"{link.bandwidth / 1e6:.2f} MB/s",
                       "-" if link.speed_factor is None else f"{link.speed_factor:.2f}")
        out.print(lt)
    _print_learned(st)
    running = [(r.robot, p) for r in st.robots for p in r.running]
    if running:
        progs = Table(title="running programs", title_justify="left")
        for name in ("host", "program", "origin", "progress"):
            progs.add_column(name, justify="right" if name == "progress" else "left")
        for host, p in running:
            progs.add_row(host, p.program, p.origin, "-" if p.progress is None else f"{100 * p.progress:.0f}%")
        out.print(progs)


def _print_accelerators(st: Any) -> None:
    """``ramps status``'s table of the accelerators each robot offers, if any does."""
    from rich.table import Table

    accels = [(r.robot, a) for r in st.robots for a in r.accelerators]
    if accels:  # what programs that can use one are priced by (ramps.core.accelerators)
        at = Table(title="accelerators each robot offers", title_justify="left")
        for name in ("robot", "kind", "slots", "speed", "programs", "memory free", "utilisation"):
            at.add_column(name, justify="left" if name in ("robot", "kind") else "right")
        for robot, a in accels:
            at.add_row(robot, a.kind, str(a.count), f"{a.speed:g}", str(a.running),
                       f"{a.memory_free / 2**30:.1f} of {a.memory_total / 2**30:.1f} GiB" if a.memory_total else "-",
                       "-" if a.utilisation is None else f"{100 * a.utilisation:.0f}%")
        out.print(at)


def _print_batteries(st: Any) -> None:
    """``ramps status``'s table of the robots' batteries, if any reports one."""
    from rich.table import Table

    robots = [r for r in st.robots if r.battery is not None]
    if robots:  # a robot below its reserve takes no teammates' programs (ramps.core.battery)
        bt = Table(title="batteries (below its reserve a robot takes no teammates' programs)", title_justify="left")
        for name in ("robot", "charge", "state", "watts per busy core"):
            bt.add_column(name, justify="left" if name in ("robot", "state") else "right")
        for r in robots:
            bt.add_row(r.robot, f"{100 * r.battery:.0f}%",
                       "[yellow]low: runs only its own programs[/]" if r.low_battery else "ok",
                       "-" if r.power is None else f"{r.power:.3g}")
        out.print(bt)


def _print_learned(st: Any) -> None:
    """``ramps status``'s table of the work origins learned, if any did."""
    from rich.table import Table

    learned = [(r.robot, w) for r in st.robots for w in r.learned]
    if learned:
        wt = Table(title="work learned from completed runs (placements use it instead of the declared work)",
                   title_justify="left")
        for name in ("origin", "program", "work units"):
            wt.add_column(name, justify="right" if name == "work units" else "left")
        for robot, w in learned:
            wt.add_row(robot, w.program, f"{w.work:.3g}")
        out.print(wt)
