"""What the two-site experiment reports (``ramps.lab.sites.run_sites``), and how it is printed.

How this works: ``SitesReport`` holds one run: the time for the two sites to
join, each layout's batches (``PlacementRun``, ``Batch``: where each kind of
program ran and how long it took), and with an outage what happened while
router A was down (``Outage``). ``format_report`` prints it as text
(``ramps testbed experiment sites``); ``--json`` writes the records as they are.
"""

from __future__ import annotations

import msgspec


class Batch(msgspec.Struct, kw_only=True):
    """One kind of program submitted at once from r1: where they ran and how long they took."""

    kind: str
    programs: int
    payload: int
    units: float
    site_a: int
    site_b: int
    per_robot: dict[str, int]
    makespan: float
    mean: float


class PlacementRun(msgspec.Struct, kw_only=True):
    """The two batches on one team: two sites behind routers, or one site."""

    layout: str
    #: r1's measured links when it submitted: robot -> [latency s, bandwidth B/s]
    links: dict[str, list[float | None]]
    batches: list[Batch]


class Outage(msgspec.Struct, kw_only=True):
    """Router A killed and restarted while origins in both sites submit."""

    router_down_s: float
    submitted: dict[str, int]
    delivered: dict[str, int]
    lost: int
    duplicated: int
    #: programs each origin got done while the sites were apart (killed .. whole again)
    done_while_apart: dict[str, int]
    #: where the programs of each origin ran while apart, by site
    hosts_while_apart: dict[str, dict[str, int]]
    #: what site B saw while apart: robots alive
    b_saw_while_apart: list[str]
    heal_s: float


class SitesReport(msgspec.Struct, kw_only=True):
    __test__ = False
    mode: str
    per_site: int
    rate: float | None
    quota: float
    join_s: float
    placement: list[PlacementRun]
    outage: Outage | None


def fmt(x: float | None, scale: float, unit: str) -> str:
    """``x`` times ``scale`` in ``unit``, three digits; "-" for None."""
    return "-" if x is None else f"{x * scale:.3g} {unit}"


def format_report(rep: SitesReport) -> str:
    lines = [f"two sites of {rep.per_site} robots ({rep.mode} mode) behind two routers, routers' link "
             f"{'full speed' if not rep.rate else f'{rep.rate / 1e3:g} kB/s (tbf)'}; each robot {rep.quota:g} "
             f"of a host core; one team {rep.join_s:.1f} s after the testbed started", ""]
    lines.append(f"{'layout':<10} {'programs':<34} {'site A':>6} {'site B':>6} {'makespan':>9} {'mean':>7}")
    for run in rep.placement:
        for b in run.batches:
            what = f"{b.programs} x {b.kind} ({b.payload / 1e3:g} kB, {b.units:g} u)"
            lines.append(f"{run.layout:<10} {what:<34} {b.site_a:>6} {b.site_b:>6} {b.makespan:>8.1f}s "
                         f"{b.mean:>6.1f}s")
    for run in rep.placement:
        same = [v for r, v in run.links.items() if int(r[1:]) <= rep.per_site]
        other = [v for r, v in run.links.items() if int(r[1:]) > rep.per_site]
        lines.append(f"r1's links ({run.layout}): r2-r{rep.per_site} "
                     + ", ".join(fmt(v[1], 1e-3, "kB/s") for v in same)
                     + f"; r{rep.per_site + 1}-r{2 * rep.per_site} "
                     + ", ".join(fmt(v[1], 1e-3, "kB/s") for v in other))
    if rep.placement and len(rep.placement) == 1:
        lines.append("(no same-site run)")
    o = rep.outage
    if o is not None:
        lines += ["", f"router A killed for {o.router_down_s:.1f} s while r1 (site A) and r{rep.per_site + 1} "
                      f"(site B) submitted {sum(o.submitted.values())} programs:",
                  f"  delivered {sum(o.delivered.values())}, lost {o.lost}, duplicated {o.duplicated}; done while "
                  f"apart {o.done_while_apart} (by site of the host: {o.hosts_while_apart})",
                  f"  site B saw {', '.join(o.b_saw_while_apart) or 'nobody'} while apart; the team was whole "
                  f"again {o.heal_s:.1f} s after router A restarted"]
    return "\n".join(lines)
