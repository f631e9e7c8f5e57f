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
router) or ``--mode client`` (they link to their router only). Programs of
``ramps.testbed.slowlink.crunch`` carry parameters of a chosen size and
burn a chosen amount of work.

``run_sites`` is the experiment (``ramps testbed experiment sites``):

1. *one team*: the eight robots join; every one sees the seven others.
2. *placement across sites*: r1 (site A) measures its links (same-site and
   cross-site, ``LoadReport.links``), then submits programs with large
   parameters and little work, and programs with small parameters and much
   work. Printed beside a *same-site run*: the same programs on eight
   robots of one bridge, no routers.
3. *a router crash*: origins r1 (site A) and r5 (site B) keep submitting;
   router A is SIGKILLed and started again later. Both sites keep running
   programs while apart; every program is delivered, none lost or doubled;
   the time until the team is whole again is measured.

The report's records and its text are in ``ramps.testbed.sites_report``.

Rules: root only; everything is removed on exit (the two testbeds' own
``down()``; the link between the routers dies with their namespaces).
"""

from __future__ import annotations

import subprocess
import time
from collections import Counter
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from ramps.testbed import net
from ramps.testbed.bed import PORT, Testbed, watch_team
from ramps.testbed.procs import TestbedError
from ramps.testbed.sessions import root_config, team_client
from ramps.testbed.sites_report import Batch, Outage, PlacementRun, SitesReport, fmt

if TYPE_CHECKING:
    import zenoh

#: the router's slot among a site's "robots" (its namespace, cgroup and process)
ROUTER = "rt"
#: the program the experiment runs (registered on every node)
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


# ====================================================================== the experiment
def _links(obs, of: str, robots: list[str]) -> dict[str, list[float | None]]:
    rep = obs.report(of)
    seen = {link.robot: [link.latency, link.bandwidth] for link in (rep.links if rep else [])}
    return {r: seen.get(r, [None, None]) for r in robots if r != of}


def _wait_links(obs, robots: list[str], timeout: float) -> dict[str, list[float | None]]:
    deadline = time.monotonic() + timeout
    while True:
        links = _links(obs, "r1", robots)
        if all(v[1] is not None for v in links.values()) or time.monotonic() > deadline:
            return links
        time.sleep(0.5)


def _batches(team, site_a: list[str], *, large: tuple[int, int, float], cpu: tuple[int, int, float],
             log: Callable[[str], None]) -> list[Batch]:
    out = []
    for kind, (n, payload, units) in (("large parameters", large), ("CPU-heavy, small", cpu)):
        data = b"\x5a" * payload
        t0 = time.monotonic()
        futs = [team.options(work=units).submit("crunch", data=data, units=units) for _ in range(n)]
        took = []
        for f in futs:
            f.result(timeout=600)
            took.append(time.monotonic() - t0)
        hosts = Counter(f.host for f in futs)
        a = sum(c for h, c in hosts.items() if h in site_a)
        b = Batch(kind=kind, programs=n, payload=payload, units=units, site_a=a, site_b=n - a,
                  per_robot=dict(sorted(hosts.items())), makespan=round(max(took), 2),
                  mean=round(sum(took) / n, 2))
        log(f"  {kind}: {n} x ({payload / 1e3:g} kB, {units:g} units): site A {b.site_a}, site B {b.site_b} "
            f"{dict(sorted(hosts.items()))}, makespan {b.makespan:.1f} s")
        out.append(b)
        time.sleep(2.0)  # the hosts' load reports settle before the next batch
    return out


def run_sites(*, per_site: int = 4, mode: str = "peer", rate: float = 250e3, quota: float | None = None,
              cores: int = 2, large: tuple[int, int, float] = (8, 1_000_000, 0.05),
              cpu: tuple[int, int, float] = (16, 100, 1.0), outage: float = 8.0, stream: int = 12,
              same_site: bool = True, log: Callable[[str], None] | None = None) -> SitesReport:
    """The experiment of the module docstring; ``large`` and ``cpu`` are
    (programs, parameter bytes, work units) of the two batches."""
    log = log or (lambda _m: None)
    import os

    quota = quota if quota is not None else round(max(0.05, len(os.sched_getaffinity(0)) / (2 * per_site + 2)), 3)
    config = {"core": {"probe_period": 2.0}}
    placement: list[PlacementRun] = []
    t_up = time.monotonic()
    with Sites(per_site, mode=mode, rate=rate, quota=quota, cores=cores, config=config) as s:
        join = time.monotonic() - t_up
        log(f"two sites of {per_site} ({mode} mode), routers linked at {rate / 1e3:g} kB/s: one team of "
            f"{len(s.robots)} ({join:.1f} s from nothing to every robot seeing the {len(s.robots) - 1} others)")
        with watch_team(s.a) as obs:
            links = _wait_links(obs, s.robots, 60.0)
        log("  r1's measured links: " + ", ".join(
            f"{r} {fmt(v[0], 1e3, 'ms')}/{fmt(v[1], 1e-3, 'kB/s')}" for r, v in links.items()))
        with s.a.client("r1", timeout=60.0) as team:
            placement.append(PlacementRun(layout="two sites", links=links,
                                          batches=_batches(team, s.a.members, large=large, cpu=cpu, log=log)))
        out = _outage(s, outage=outage, stream=stream, log=log) if outage > 0 else None
    if same_site:
        log(f"same site: {2 * per_site} robots on one bridge, no routers")
        names = [f"r{i}" for i in range(1, 2 * per_site + 1)]
        with Testbed(names, quota=quota, cores=cores, programs=[TARGET], lease_ms=2000, config=config) as tb, \
                watch_team(tb) as obs:
            links = _wait_links(obs, names, 60.0)
            with tb.client("r1", timeout=60.0) as team:
                placement.append(PlacementRun(layout="one site", links=links, batches=_batches(
                    team, names[:per_site], large=large, cpu=cpu, log=log)))
    return SitesReport(mode=mode, per_site=per_site, rate=rate, quota=quota, join_s=round(join, 2),
                       placement=placement, outage=out)


def _outage(s: Sites, *, outage: float, stream: int, log: Callable[[str], None]) -> Outage:
    """Origins r1 (site A) and r5 (site B) submit ``stream`` programs each, one
    every 0.5 s; router A is killed 1 s in and started again ``outage`` s later."""
    import threading

    origins = {s.a.members[0]: s.a, s.b.members[0]: s.b}
    lock = threading.Lock()
    errors: list[str] = []
    done_at: dict[str, list[tuple[float, str | None]]] = {o: [] for o in origins}
    futures: dict[str, list[Any]] = {o: [] for o in origins}

    def done(origin: str, f: Any) -> None:
        with lock:
            if not f.cancelled() and f.exception() is None:
                done_at[origin].append((time.monotonic(), f.host))

    def run(origin: str, site: SiteTestbed) -> None:
        try:
            with site.client(origin, timeout=60.0) as team:
                for _ in range(stream):
                    f = team.options(work=0.3).submit("crunch", data=b"x" * 100, units=0.3)
                    f.add_done_callback(lambda f, o=origin: done(o, f))
                    futures[origin].append(f)
                    time.sleep(0.5)
                for f in futures[origin]:
                    try:
                        f.result(timeout=300)
                    except Exception as exc:  # lost: counted
                        with lock:
                            errors.append(f"{origin}: {type(exc).__name__}: {exc}")
        except Exception as exc:
            with lock:
                errors.append(f"{origin}: client failed: {type(exc).__name__}: {exc}")

    log(f"router crash: origins {', '.join(origins)} submit {stream} programs each; router A killed 1 s in, "
        f"started again {outage:g} s later")
    threads = [threading.Thread(target=run, args=(o, site), daemon=True) for o, site in origins.items()]
    with watch_team(s.b) as obs_b:
        for t in threads:
            t.start()
        time.sleep(1.0)
        s.a.crash(ROUTER)
        killed = time.monotonic()
        saw: set[str] | None = None
        while time.monotonic() - killed < outage:
            time.sleep(0.25)
            if time.monotonic() - killed > 3.0:  # past the lease: whom site B sees while apart
                saw = set(obs_b.ready()) if saw is None else saw & obs_b.ready()
        s.a.start_router()
        back = time.monotonic()
    heal = s.wait_whole(120.0)
    whole_at = time.monotonic()
    log(f"  router A down {back - killed:.1f} s; site B saw {sorted(saw or [])} while apart; "
        f"team whole again {heal:.1f} s after router A restarted")
    for t in threads:
        t.join(600)
    site_of = {r: "A" for r in s.a.members} | {r: "B" for r in s.b.members}
    during = {o: [h for t, h in done_at[o] if killed <= t <= whole_at] for o in origins}
    delivered = {o: len(done_at[o]) for o in origins}
    out = Outage(router_down_s=round(back - killed, 2), submitted={o: len(futures[o]) for o in origins},
                 delivered=delivered, lost=len(errors), duplicated=sum(max(0, delivered[o] - stream) for o in origins),
                 done_while_apart={o: len(v) for o, v in during.items()},
                 hosts_while_apart={o: dict(Counter(site_of.get(h or "", "?") for h in v)) for o, v in during.items()},
                 b_saw_while_apart=sorted(saw or []), heal_s=round(heal, 2))
    log(f"  delivered {delivered} of {stream} each, lost {out.lost}, duplicated {out.duplicated}; done while "
        f"apart: {out.done_while_apart} (by site {out.hosts_while_apart})")
    for e in errors[:5]:
        log(f"  lost: {e}")
    return out
