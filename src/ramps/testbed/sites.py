"""Two sites behind two routers on the testbed: one team across networks.

How this works::

    site A: bridge rb-<tbA>, 10.201.A.0/24          site B: bridge rb-<tbB>, 10.201.B.0/24
      rt (router A) 10.201.A.1  eth1 10.202.A.1 ==== eth1 10.202.A.2  rt (router B) 10.201.B.1
      r1 .. r4      10.201.A.2-5       (a veth, slowed with tbf)      r5 .. r8      10.201.B.2-5

Each site is a ``SiteTestbed``: a ``Testbed`` (namespaces, cpu cgroups, the
robots' nodes) whose first "robot" ``rt`` is the site's router: its own
namespace on the site's bridge and its own cgroup, running ``ramps router``
instead of ``ramps node`` (so crash, restart, clean-up and ``ramps testbed
down --all`` treat it like any robot of the testbed). The two router
namespaces are joined by one veth (``eth1`` in each, ``10.202.A.0/24``),
optionally slowed to ``rate`` bytes/s both ways with a token bucket (this
kernel has no netem: no delay can be added). Forwarding is off everywhere:
a robot reaches its own bridge and nothing else, so the only path between
the sites is robot -> router A -> router B -> robot, through Zenoh.

Robots are ``--mode peer`` (default: they link to their site mates
directly, found by multicast inside their bridge, and ``--connect`` their
router) or ``--mode client`` (they link to their router only). Every node
registers ``ramps.testbed.slowlink.crunch`` (``TARGET``): programs whose
parameters are of a chosen size and whose work is a chosen amount.

``Sites`` makes the two sites and links their routers; ``whole`` tells when
the eight robots form one team. The experiment run on them (``ramps testbed
experiment sites``) is ``ramps.lab.sites``.

Rules: root only; everything is removed on exit (the two testbeds' own
``down()``; the link between the routers dies with their namespaces).
"""

from __future__ import annotations

import subprocess
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from ramps.testbed import net
from ramps.testbed.bed import PORT, Testbed, watch_team
from ramps.testbed.procs import TestbedError
from ramps.testbed.sessions import root_config, team_client

if TYPE_CHECKING:
    import zenoh

#: the router's slot among a site's "robots" (its namespace, cgroup and process)
ROUTER = "rt"
#: the program every node registers (``ramps.testbed.slowlink.crunch``)
TARGET = "ramps.testbed.slowlink:crunch"
#: the routers' link: 10.202.<site A's X>.1 and .2
LINK_BASE = "10.202"


class SiteTestbed(Testbed):
    """One site: a ``Testbed`` whose first robot slot is the site's router (module docstring)."""

    __test__ = False

    def __init__(self, robots: list[str], *, site: str, mode: str = "peer",
                 router_connect: Callable[[], list[str]] | None = None,
                 before_router: Callable[["SiteTestbed"], None] | None = None, **kw: Any) -> None:
        if mode not in ("peer", "client"):
            raise ValueError(f"mode must be peer or client, got {mode!r}")
        super().__init__([ROUTER, *robots], **kw)
        self.site = site
        self.node_mode = mode
        self._router_connect = router_connect or (lambda: [])
        self._before_router = before_router

    @property
    def members(self) -> list[str]:
        """The robots, without the router."""
        return [r for r in self.names if r != ROUTER]

    def router_endpoint(self) -> str:
        return f"tcp/{self.ip(ROUTER)}:{PORT}"

    def _node_cmd(self, robot: str) -> list[str]:
        if robot == ROUTER:
            cmd = [self.python, "-m", "ramps.cli", "router", "--team", self.team, "--listen", f"tcp/0.0.0.0:{PORT}",
                   "--no-multicast"]
            if self.lease_ms is not None:
                cmd += ["--lease-ms", str(self.lease_ms)]
            for ep in self._router_connect():
                cmd += ["--connect", ep]
            return cmd
        rb = self.robots[robot]
        cmd = [self.python, "-m", "ramps.cli", "node", "--robot", robot, "--team", self.team,
               "--mode", self.node_mode, "--connect", self.router_endpoint(), "--no-battery-sysfs"]
        if self.node_mode == "peer":  # site mates link directly: found by multicast inside the bridge
            cmd += ["--listen", f"tcp/{rb['ip']}:{PORT}", "--multicast"]
        else:
            cmd += ["--no-multicast"]
        return cmd + self._node_options(robot)

    def _start_node(self, robot: str) -> None:
        if robot == ROUTER and self._before_router is not None:
            self._before_router(self)
        super()._start_node(robot)
        if robot == ROUTER:  # listening before the robots start: a client needs its router at once
            from ramps.runtime.admission import reachable

            deadline = time.monotonic() + 30.0
            while not reachable(self.router_endpoint(), 0.5):
                if self.process_state(ROUTER) == "dead" or time.monotonic() > deadline:
                    raise TestbedError(f"site {self.site}'s router did not start:\n{self.log_tail(ROUTER)}")
                time.sleep(0.05)

    def start_router(self) -> float:
        """Start the site's router again after ``crash(ROUTER)`` (as its supervisor
        would); return the seconds until it listens."""
        t0 = time.monotonic()
        with self._lock:
            self.procs.kill(ROUTER)  # whatever is left of the old one
            rb = self._robot(ROUTER)
            rb["faults"] = [f for f in rb["faults"] if f != "crashed"]
            self._start_node(ROUTER)  # returns once it listens
            self._save()
        return time.monotonic() - t0

    def wait_alive(self, robots: list[str] | None = None, timeout: float = 60.0) -> float:
        """As ``Testbed.wait_alive``, for the robots only (a router holds no token)."""
        want = [r for r in (robots or self.names) if r != ROUTER]
        return super().wait_alive(want, timeout) if want else 0.0

    def zenoh_config(self) -> zenoh.Config:
        """An observer in the root namespace: a client of this site's router."""
        return root_config("client", [self.router_endpoint()])

    def client(self, robot: str = "r1", *, timeout: float = 10.0, lease_ms: int | None = None,
               **options: Any) -> Any:
        """A ``Team`` in the root namespace whose programs start on ``robot``: a
        peer linked to that robot only (peer mode: the application beside its
        node, which keeps working while the router is away), or a client of the
        site's router (client mode)."""
        self._robot(robot)
        if self.node_mode == "peer":
            # gossip off: the root namespace reaches both bridges, and this client must not
            # link to robots of the other site by itself (only the routers join the sites)
            flags: dict[str, Any] = dict(connect=[self.endpoint(robot)], zenoh={"scouting/gossip/enabled": False})
        else:
            flags = dict(mode="client", connect=[self.router_endpoint()])
        return team_client(self.team, robot, flags, timeout=timeout, lease_ms=lease_ms, **options)


class Sites:
    """Two ``SiteTestbed``s whose routers are linked (module docstring).

    >>> with Sites(4, rate=250e3) as s:
    ...     team = s.a.client("r1"); ...; s.a.crash(ROUTER); s.a.start_router()
    """

    __test__ = False

    def __init__(self, per_site: int = 4, *, mode: str = "peer", rate: float | None = None,
                 quota: float | None = None, cores: int | None = None, lease_ms: int | None = 2000,
                 programs: list[str] | None = None, config: dict[str, Any] | None = None,
                 speed: float | None = None) -> None:
        names_a = [f"r{i}" for i in range(1, per_site + 1)]
        names_b = [f"r{i}" for i in range(per_site + 1, 2 * per_site + 1)]
        self.rate = rate
        self.mode = mode
        common: dict[str, Any] = dict(mode=mode, quota=quota, cores=cores, lease_ms=lease_ms, speed=speed,
                                      programs=list(programs or [TARGET]), config=config or {})
        import uuid

        self.team = f"sites-{uuid.uuid4().hex[:6]}"  # both sites': a testbed names its team only once up
        self.a = SiteTestbed(names_a, site="A", team=self.team, **common)
        self.b = SiteTestbed(names_b, site="B", team=self.team, router_connect=lambda: [self.link_endpoint()],
                             before_router=self._link_routers, **common)
        self.link: list[str] = []

    # ------------------------------------------------------------ the routers' link
    def link_ip(self, side: int) -> str:
        return f"{LINK_BASE}.{self.a.x}.{side}"

    def link_endpoint(self) -> str:
        """Router A's address on the link between the routers (router B dials it)."""
        return f"tcp/{self.link_ip(1)}:{PORT}"

    def _link_routers(self, b: SiteTestbed) -> None:
        """A veth between the two router namespaces (called once site B's namespaces exist)."""
        ns_a, ns_b = self.a.namespace(ROUTER), b.namespace(ROUTER)
        host, peer = f"{net.LINK_PREFIX}{self.a.tb}-ln", f"{net.LINK_PREFIX}{self.a.tb}-lp"
        net.ip("link", "add", host, "type", "veth", "peer", "name", peer)
        for dev, ns, side in ((host, ns_a, 1), (peer, ns_b, 2)):
            net.ip("link", "set", dev, "netns", ns)
            net.ip("link", "set", dev, "name", "eth1", ns=ns)
            net.ip("addr", "add", f"{self.link_ip(side)}/24", "dev", "eth1", ns=ns)
            net.ip("link", "set", "eth1", "up", ns=ns)
        self.link = [ns_a, ns_b]
        if self.rate:
            self.shape(self.rate)

    def shape(self, rate: float | None) -> None:
        """Slow the routers' link to ``rate`` bytes/s each way (None: full speed)."""
        from ramps.testbed.slowlink import tbf

        for ns in self.link:
            if rate:
                tbf("eth1", rate, ns=ns)
            else:
                subprocess.run(["nsenter", f"--net={net.NETNS_DIR / ns}", "tc", "qdisc", "del", "dev", "eth1",
                                "root"], capture_output=True)

    # ------------------------------------------------------------ lifecycle
    @property
    def robots(self) -> list[str]:
        return self.a.members + self.b.members

    def up(self, timeout: float = 90.0) -> "Sites":
        try:
            self.a.up(timeout)
            self.b.up(timeout)
            self.wait_whole(timeout)
        except BaseException:
            self.down()
            raise
        return self

    def wait_whole(self, timeout: float = 90.0, via: SiteTestbed | None = None) -> float:
        """Until every robot of both sites is alive and sees the 7 others (seen through
        ``via``'s router, default site B's); the seconds it took."""
        t0 = time.monotonic()
        with watch_team(via or self.b) as obs:
            while True:
                if whole(obs, self.robots):
                    return time.monotonic() - t0
                if time.monotonic() - t0 > timeout:
                    raise TimeoutError(f"the two sites did not form one team within {timeout:g} s: "
                                       f"{_sees(obs, self.robots)}")
                time.sleep(0.1)

    def down(self) -> None:
        self.b.down()
        self.a.down()

    def __enter__(self) -> "Sites":
        return self.up()

    def __exit__(self, *exc: object) -> None:
        self.down()


def _sees(obs, robots: list[str]) -> dict[str, int | None]:
    ready = obs.ready()
    return {r: (obs.report(r).sees if r in ready and obs.report(r) else None) for r in robots}


def whole(obs, robots: list[str]) -> bool:
    """Every robot alive, reporting, and seeing all the others."""
    return set(robots) <= obs.ready() and all((n or 0) >= len(robots) - 1 for n in _sees(obs, robots).values())
