"""Two sites behind two routers, the experiment: ``ramps testbed experiment sites``.

How this works: on ``ramps.testbed.sites.Sites`` (two sites of ``per_site``
robots, each site behind its own router, the routers' link slowed to
``rate`` bytes/s), ``run_sites`` measures:

1. *one team*: the eight robots join; every one sees the seven others.
2. *placement across sites*: r1 (site A) measures its links (same-site and
   cross-site, ``LoadReport.links``), then submits programs with large
   parameters and little work, and programs with small parameters and much
   work (``crunch``). Printed beside a *same-site run*: the same programs on
   eight robots of one bridge, no routers.
3. *a router crash*: origins r1 (site A) and r5 (site B) keep submitting;
   router A is SIGKILLed and started again later. Both sites keep running
   programs while apart; every program is delivered, none lost or doubled;
   the time until the team is whole again is measured.

The report's records and its text are in ``ramps.lab.sites_report``.

Rules: root only; everything is removed on exit (the two testbeds' own
``down()``; the link between the routers dies with their namespaces).
"""

from __future__ import annotations

import time
from collections import Counter
from collections.abc import Callable
from typing import Any

from ramps.lab.sites_report import Batch, Outage, PlacementRun, SitesReport, fmt
from ramps.testbed.bed import Testbed, watch_team
from ramps.testbed.sites import ROUTER, TARGET, Sites, SiteTestbed


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
