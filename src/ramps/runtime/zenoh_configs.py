"""Zenoh configurations from a node's settings: a robot's peer or client, a router.

How this works: ``zenoh_config`` and ``router_config`` build a ``zenoh.Config``
from ``NodeSettings`` (``ramps.runtime.settings``): mode, listen and connect
endpoints, multicast scouting and who dials whom, then what both share
(``_links_security_overrides``): the team's lease and keep-alives, shared
memory, on a secured team its TLS and access control, and last the raw
``zenoh`` overrides the operator wrote. ``zenoh_runtime_defaults`` sizes
Zenoh's thread pools before its first session opens in the process.
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING

from ramps.runtime.settings import DEFAULT_LISTEN, DEFAULT_TLS_LISTEN, NodeSettings, flatten_zenoh

if TYPE_CHECKING:
    import zenoh

    from ramps.runtime.credentials import Credentials


AUTOCONNECT_STRATEGY = '{peer: {to_router: "always", to_peer: "greater-zid"}}'
AUTOCONNECT_ALWAYS = '{peer: {to_router: "always", to_peer: "always"}}'
#: how often a connect endpoint that does not answer is dialled again (Zenoh's
#: defaults: 1 s, doubling up to 4 s)
CONNECT_RETRY = {"period_init_ms": 100, "period_max_ms": 2000, "period_increase_factor": 1.5}


def zenoh_config(s: NodeSettings, *, listen: list[str] | None = None, credentials: Credentials | None = None,
                 exit_on_failure: bool = False, scout_first: bool = True) -> zenoh.Config:
    """A Zenoh peer or client configuration for these settings (``s.mode``).

    ``scout_first``: ``zenoh.open`` spends Zenoh's scouting delay (0.5 s)
    finding peers before it returns, as a node should (it then meets its
    team at once); an application does not (it waits for its node's
    liveliness token anyway), so ``ramps.connect`` opens in milliseconds.

    Secure mode needs the checked ``credentials``
    (``ramps.runtime.security.Credentials``); ``exit_on_failure`` then makes
    ``zenoh.open`` fail within 3 s unless it links to every connect endpoint."""
    import json

    import zenoh

    zenoh_runtime_defaults()
    c = zenoh.Config()
    c.insert_json5("mode", json.dumps(s.mode))
    # a client links to its router only: it never listens
    listening = [] if s.mode == "client" else s.listen_endpoints(listen)
    c.insert_json5("listen/endpoints", json.dumps(listening))
    c.insert_json5("connect/endpoints", json.dumps(s.connect))
    c.insert_json5("scouting/multicast/enabled", "true" if s.multicast else "false")
    if not scout_first:
        c.insert_json5("scouting/delay", "0")
    # of two robots that find each other (multicast, gossip) only one dials: when both
    # did, a lease that expired on one side only (a robot cut or frozen just past it)
    # could leave the pair deaf to each other for good (eclipse-zenoh/zenoh#2806;
    # seen here once in about 50 cut/freeze/crash recoveries on the testbed). A peer
    # that listens nowhere (an application) cannot be dialled: it dials everyone.
    strategy = AUTOCONNECT_STRATEGY if listening else AUTOCONNECT_ALWAYS
    for how in ("multicast", "gossip"):
        c.insert_json5(f"scouting/{how}/autoconnect_strategy", strategy)
    _links_security_overrides(c, s, credentials, exit_on_failure, "zenoh_config")
    return c


def _links_security_overrides(c: zenoh.Config, s: NodeSettings, credentials: Credentials | None,
                              exit_on_failure: bool, caller: str) -> None:
    """What a robot's and a router's configurations share: how often an
    endpoint that does not answer is dialled again, the team's lease
    and keep-alives, shared memory (``s.shared_memory``: off unless asked, and
    then only for messages of ``SHM_THRESHOLD`` or more), on a secured
    team its TLS and access control (``credentials``: the checked bundle;
    ``exit_on_failure``: ``zenoh.open`` fails within 3 s unless it links to
    every connect endpoint), and last ``s.zenoh``: what the operator wrote
    wins over ramps's defaults."""
    import json

    # a teammate not up yet (robots booting together, a node restarted by its
    # supervisor) is dialled again after 0.1 s, then less often, at most every
    # 2 s: Zenoh's own 1 s then 2 s then 4 s left such a team apart for seconds
    c.insert_json5("connect/retry", json.dumps(CONNECT_RETRY))
    c.insert_json5("transport/link/tx/lease", str(s.lease_ms))
    c.insert_json5("transport/link/tx/keep_alive", "4")
    c.insert_json5("transport/shared_memory/enabled", "true" if s.shared_memory else "false")
    if s.shared_memory:
        c.insert_json5("transport/shared_memory/transport_optimization/message_size_threshold",
                       str(SHM_THRESHOLD))
    if s.secure:
        from ramps.runtime.security import secure_zenoh_json

        if credentials is None:
            raise ValueError(f"secure mode: {caller} needs the checked credentials")
        for key, value in secure_zenoh_json(s.team, credentials, members=s.members).items():
            c.insert_json5(key, json.dumps(value))
        if exit_on_failure and s.connect:
            c.insert_json5("connect/exit_on_failure", "true")
            c.insert_json5("connect/timeout_ms", str(CONNECT_TIMEOUT_MS))
    for key, value in flatten_zenoh(s.zenoh).items():
        c.insert_json5(key, json.dumps(value))


#: with ``shared_memory`` on, the smallest message that goes through it (Zenoh's
#: default: 3 KB). Below it shared memory saves nothing measurable (100 KB
#: arguments: the same latency either way), and nodes on one host probing each
#: other (16 KB) would each fill their 16 MiB pool and map every teammate's
SHM_THRESHOLD = 64 * 1024


#: where a router listens unless told (Zenoh's usual router port)
DEFAULT_ROUTER_LISTEN = "tcp/0.0.0.0:7447"
DEFAULT_ROUTER_TLS_LISTEN = "tls/0.0.0.0:7447"


def router_listen(s: NodeSettings) -> list[str]:
    """A router's listen endpoints: ``s.listen``, the node default (any port)
    made the router's port 7447 (TLS on a secured team)."""
    default = DEFAULT_ROUTER_TLS_LISTEN if s.secure else DEFAULT_ROUTER_LISTEN
    return [default if e in (DEFAULT_LISTEN, DEFAULT_TLS_LISTEN) else e for e in s.listen]


def router_config(s: NodeSettings, *, credentials: Credentials | None = None,
                  exit_on_failure: bool = False) -> zenoh.Config:
    """A Zenoh router configuration for these settings (``ramps router``):
    listen on ``router_listen(s)``, link to the routers of ``s.connect``
    (other sites), the team's lease, and on a secured team the same TLS and
    access control as its robots (``credentials``: the router's own bundle
    from ``ramps team add``). ``s.mode`` is not used: this is a router."""
    import json

    import zenoh

    zenoh_runtime_defaults()
    c = zenoh.Config()
    c.insert_json5("mode", '"router"')
    c.insert_json5("listen/endpoints", json.dumps(router_listen(s)))
    c.insert_json5("connect/endpoints", json.dumps(s.connect))
    c.insert_json5("scouting/multicast/enabled", "true" if s.multicast else "false")
    _links_security_overrides(c, s, credentials, exit_on_failure, "router_config")
    return c


#: Zenoh's thread pools, unless ZENOH_RUNTIME is set already. When Zenoh gives
#: up on a peer (its lease expired: the robot dropped off the network), it
#: closes that peer's TCP link with a blocking close() on one of its receive
#: threads. The socket has SO_LINGER 10 s and holds data the dead peer can
#: never acknowledge, so the thread is stuck for 10 s (eclipse-zenoh/zenoh#1101;
#: linger is a compile-time constant). With Zenoh's default of 2 receive
#: threads a robot's one or two links to the lost peer took both, and the
#: robot heard nobody for 10 s from about 1.6 s after the loss: on the testbed
#: every teammate did, and wrote healthy robots off for missing heartbeats.
#: Zenoh 1.10.2 still does: with 4 receive threads, 4 robots of 7 cut off at
#: once left the other 3 deaf to each other for 7-8 s, and healthy ones were
#: written off; with 16 the longest gap was 1.1 s. Idle, 4 threads instead of
#: 16 changed neither a node's CPU nor its memory measurably
#: (docs/lab/2026-11-27-footprint.md).
ZENOH_RUNTIME_DEFAULT = "(rx: (worker_threads: 16))"


def zenoh_runtime_defaults() -> None:
    """Apply ZENOH_RUNTIME_DEFAULT unless the user set ZENOH_RUNTIME. Zenoh
    reads it when its first session opens in this process."""
    os.environ.setdefault("ZENOH_RUNTIME", ZENOH_RUNTIME_DEFAULT)


#: secure mode: how long ``zenoh.open`` may try to link to the connect endpoints
CONNECT_TIMEOUT_MS = 3000
