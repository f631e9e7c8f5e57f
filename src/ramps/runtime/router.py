"""A Zenoh router for a site of robots (``ramps router``).

How this works: ramps robots are Zenoh peers that link straight to each
other on one network. Robots on two networks (a warehouse's two halls, a
depot and a yard) reach each other through routers: each site runs one
router that its robots ``--connect`` to, and the routers ``--connect`` to
each other. Data and liveliness then flow robot -> router -> router ->
robot, and the team is one team (docs/sites-and-routers.md).

The router is Zenoh's own, opened in this process by the ``zenoh`` Python
package ramps already depends on (``zenoh.open`` with ``mode: "router"``):
nothing else to install, the same version of Zenoh as the nodes, and the
same settings (``NodeSettings``: listen, connect, lease, multicast, raw
``zenoh`` overrides) and the same security (``router_config``: a secured
team's router holds a team certificate from ``ramps team add`` and applies
the team's access control). ``zenohd`` would do the same job but is a
separate binary that is not on PyPI and would have to match the nodes'
Zenoh version by hand.

What a router does not do: it runs no programs and holds no state of the
team; killing it only cuts its site off from the other sites (robots of a
site in peer mode keep their direct links) until it is back, and the
robots' links come back by themselves (the side holding ``connect`` dials
again).

Rules: Zenoh errors become ``TransportError`` (or ``NotAdmitted`` for a
refused secured link) with Zenoh's words and the fix; ``close()`` is
idempotent and always called (a session left open hangs the interpreter
at exit).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from ramps.errors import TransportError
from ramps.runtime.settings import NodeSettings
from ramps.runtime.zenoh_configs import router_config, router_listen


@dataclass(frozen=True)
class RouterLinks:
    """Whom a router is linked to now: other routers and the peers (robots in
    peer mode); Zenoh ids."""

    routers: tuple[str, ...]
    peers: tuple[str, ...]


class Router:
    """A Zenoh router for ``settings`` (see the module docstring).

    >>> with Router.open(load_settings(flags={"connect": ["tcp/10.0.2.1:7447"]}, default_robot=False)) as r:
    ...     print(r.listening, r.links())
    """

    def __init__(self, session: Any, settings: NodeSettings, credentials: Any = None) -> None:
        self.session = session
        self.settings = settings
        self.credentials = credentials
        self.listening = router_listen(settings)
        self._closed = False

    @classmethod
    def open(cls, settings: NodeSettings) -> "Router":
        import zenoh

        from ramps.runtime.transport import explain_open_error

        zenoh.try_init_log_from_env()
        creds = None
        try:
            if settings.secure:
                from ramps.runtime.security import admission, open_session, settings_credentials

                creds = settings_credentials(settings)  # CredentialsError: at once, before Zenoh
                fast = admission(settings.connect, creds, team=settings.team)
                session = open_session(lambda f: router_config(settings, credentials=creds, exit_on_failure=f),
                                       settings.connect, creds, team=settings.team, fail_fast=fast)
            else:
                session = zenoh.open(router_config(settings))
        except zenoh.ZError as exc:
            raise TransportError(f"cannot open a Zenoh router on {', '.join(router_listen(settings))}: "
                                 f"{explain_open_error(settings, exc)}") from exc
        return cls(session, settings, creds)

    @property
    def zid(self) -> str:
        return str(self.session.info.zid())

    def links(self) -> RouterLinks:
        info = self.session.info
        return RouterLinks(routers=tuple(sorted(str(z) for z in info.routers_zid())),
                           peers=tuple(sorted(str(z) for z in info.peers_zid())))

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self.session.close()

    def __enter__(self) -> "Router":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


__all__ = ["Router", "RouterLinks"]
