"""ramps: Reliable Autonomous Mobile Programs for robot teams.

Decentralised, fault-tolerant sharing of computational work across a team of
robots, after Valkov, Trinder & Chechina (Autonomous Robots, 2021).

Layout:
    ramps.core         sans-I/O protocol and decision logic (no clock, no network)
    ramps.sim          discrete-event simulator that drives ramps.core unchanged
    ramps.experiments  the paper's experiments, metrics and benchmarks
    ramps.cli          the ``ramps`` command
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING

from ramps.version import __version__ as __version__

if TYPE_CHECKING:
    from ramps.runtime.client import Team
    from ramps.runtime.registry import Registry


def connect(team: str | None = None, robot: str | None = None, *, connect: list[str] | None = None,
            listen: list[str] | None = None, multicast: bool | None = None, timeout: float = 5.0,
            config_file: str | os.PathLike | None = None, registry: Registry | None = None,
            secure: bool | None = None, credentials: str | os.PathLike | None = None,
            origin_grace: float = 30.0, mode: str | None = None) -> Team:
    """Join a team as an application and return a ``Team`` to submit programs to.

    The ``Team`` reaches one robot's node, which becomes the *origin* of
    every program you submit: it places each on the team, keeps it alive
    through failures and sends you its one result. Arguments left at None
    come from the environment, then the config file, then the defaults
    (the same settings as ``ramps node``'s; see ``ramps node --help``):

    team
        the team's name (env ``RAMPS_TEAM``; default ``"lab"``). Only
        robots of the same team see each other.
    robot
        the node to submit to (default: the one named after this host,
        else any node found).
    connect
        Zenoh endpoints of nodes (or a router) to dial, e.g.
        ``["tcp/192.168.1.12:7447"]`` (env ``RAMPS_CONNECT``; default
        none). Needed where multicast does not reach: most networks, and
        loopback.
    listen
        endpoints this client listens on (env ``RAMPS_LISTEN``; default
        ``tcp/0.0.0.0:0`` when it connects nowhere, none when it does).
    multicast
        find the team by UDP multicast scouting (env ``RAMPS_MULTICAST``;
        default True; pass False with ``connect`` on loopback).
    timeout
        seconds to wait for the node; ``NoTeam`` after that (default 5).
    config_file
        a TOML config file, as ``ramps node --config`` (env ``RAMPS_CONFIG``).
    registry
        the programs this client knows, to check arguments before sending
        (default: the built-ins and every function decorated with
        ``@ramps.program`` in this process); others are checked by the node.
    secure, credentials
        join a secured team with this robot's credentials directory (from
        ``ramps team add``; env ``RAMPS_SECURE``, ``RAMPS_CREDENTIALS``).
        Bad credentials raise ``CredentialsError``; a team that will not
        admit them raises ``NotAdmitted`` at once, as does a secured team
        joined without ``secure``.
    origin_grace
        seconds to wait for the origin node to come back (a restart by its
        supervisor) before its pending programs fail with ``ProgramLost``
        (default 30); a node with a durable record resumes them.
    mode
        Zenoh's ``"peer"`` (default) or ``"client"``: reach the team through
        the router given in ``connect`` (env ``RAMPS_MODE``).

    Returns a ``ramps.runtime.client.Team`` (close it, or use ``with``).
    Its ``submit(name, **arguments)`` returns a ``concurrent.futures.Future``
    (a ``ProgramFuture``); arguments are checked against the program's
    signature and annotated types before anything is sent (``BadArguments``).
    Errors are the ``ramps.errors`` tree.

    Example, with a node running on this machine (``ramps node --robot r1
    --no-multicast --listen tcp/127.0.0.1:7447``)::

        import ramps

        with ramps.connect(team="lab", robot="r1", connect=["tcp/127.0.0.1:7447"],
                           multicast=False) as team:
            print(team.submit("route_plan", picks=8, seed=3).result())
            plans = list(team.map("route_plan", [{"seed": s} for s in range(6)]))
    """
    from ramps.runtime.client import connect as _connect

    return _connect(team, robot, connect=connect, listen=listen, multicast=multicast, timeout=timeout,
                    config_file=config_file, registry=registry, secure=secure, credentials=credentials,
                    origin_grace=origin_grace, mode=mode)


def program(*args, **kwargs):
    """Register a function as a ramps program; see ``ramps.runtime.registry.program``."""
    from ramps.runtime.registry import program as _program

    return _program(*args, **kwargs)


def progress(fraction: float, detail: str = "") -> bool:
    """From inside a running program: report how far it is (0..1).

    The fraction reaches the caller's future (``fut.progress``), ``ramps
    status`` and ROS action feedback. Outside a ramps worker it does nothing;
    see ``ramps.runtime.running.report_progress``."""
    from ramps.runtime.running import report_progress

    return report_progress(fraction, detail)


def checkpoint(state) -> bool:
    """From inside a running program: save its state, so that if it is moved
    to another robot or restarted after a failure it resumes from here
    (``ramps.resume()``) instead of starting over.

    ``state`` is bytes or anything msgspec can encode (dicts, lists, numbers,
    strings, Structs), at most 256 KiB encoded (``ValueError`` beyond, and
    ``TypeError`` for what cannot be encoded, also outside a worker). Report
    ``ramps.progress`` before it, so the origin knows how much work is left.
    Returns whether it was sent: at most five a second are, and outside a
    ramps worker none is. See ``ramps.runtime.running.save_checkpoint``."""
    from ramps.runtime.running import save_checkpoint

    return save_checkpoint(state)


def accelerator():
    """From inside a running program: the accelerator its robot gave it, or
    None when it runs on a CPU (a robot without one, or outside a ramps
    worker). Its ``device`` is what to hand the program's library
    (``torch.device(grant.device)``, ``cupy.cuda.Device(grant.index)``); on an
    emulated accelerator (a testbed's), ``grant.emulate(work)`` stands in
    for the device's work. See docs/accelerators.md."""
    from ramps.runtime.running import accelerator_grant

    return accelerator_grant()


def resume():
    """From inside a running program: the state it saved with
    ``ramps.checkpoint`` in an earlier attempt (decoded: bytes come back as
    bytes, other values as their plain msgpack form, e.g. a dict), or None on
    a fresh start (and outside a ramps worker)."""
    from ramps.runtime.running import resume_state

    return resume_state()
