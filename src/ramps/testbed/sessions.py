"""Zenoh sessions in the root namespace on a testbed's team.

How this works: the host's root namespace reaches every robot over the
testbed's bridge. ``team_client`` opens a ``ramps.runtime.client.Team``
there (an application whose programs start on one robot), ``root_config``
is a plain Zenoh config for it, and ``open_watcher`` opens a
``ramps.runtime.watch.TeamWatcher`` with such a config: liveliness and
the latest load report of each robot (readiness, status, experiments).
None of them scouts by multicast or uses shared memory, as the robots do
not (``ramps.testbed.robots.RobotProcesses.spawn``).

A watcher, not a ``Team``, tells readiness and status because its
``with`` block closes it whatever interrupts it (a Ctrl-C in the middle
of ``Team()`` would leave a session whose thread blocks exit).
"""

from __future__ import annotations

import json
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import zenoh

    from ramps.runtime.watch import TeamWatcher


def team_client(team: str, robot: str, flags: dict[str, Any], *, timeout: float, lease_ms: int | None,
                **options: Any) -> Any:  # a Team: typed so, mypy cannot infer callers' lambdas with defaults
    """A ``Team`` of ``team`` whose programs start on ``robot``; ``flags``: its
    node settings over these (``connect`` at least); ``options``: more of ``Team``'s."""
    from ramps.runtime.client import Team
    from ramps.runtime.settings import load_settings

    flags = {"team": team, "multicast": False, "shared_memory": False, "listen": [], **flags}
    if lease_ms is not None:
        flags["lease_ms"] = lease_ms
    s = load_settings(flags=flags, default_robot=False, environ={})
    return Team(s, robot=robot, timeout=timeout, **options)


def root_config(mode: str, connect: list[str]) -> zenoh.Config:
    """A plain Zenoh config (``mode``: peer or client) dialling ``connect``."""
    import zenoh

    from ramps.runtime.zenoh_configs import zenoh_runtime_defaults

    zenoh_runtime_defaults()  # a lost robot must not make the observer deaf either
    c = zenoh.Config()
    c.insert_json5("mode", json.dumps(mode))
    if mode == "peer":
        c.insert_json5("listen/endpoints", "[]")
    c.insert_json5("connect/endpoints", json.dumps(connect))
    c.insert_json5("scouting/multicast/enabled", "false")
    c.insert_json5("transport/shared_memory/enabled", "false")
    return c


def open_watcher(config: zenoh.Config, team: str, *, redial: bool = False) -> TeamWatcher:
    """A watcher of ``team`` on a session opened with ``config``.

    ``redial``: an endpoint that does not answer yet is dialled again every
    0.1-0.5 s, not Zenoh's 1 s backing off to 4 s: for a watcher opened
    while the nodes still start (``Testbed.wait_alive``), which with the
    default saw robots up to 4 s after they had joined."""
    from ramps.runtime.watch import TeamWatcher

    if redial:
        config.insert_json5("connect/retry", "{period_init_ms: 100, period_max_ms: 500, period_increase_factor: 2}")
    return TeamWatcher.open(config, team)
