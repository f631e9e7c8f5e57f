"""A Zenoh session split for good (eclipse-zenoh/zenoh#2806), reproduced on the testbed.

How this works: two robots that dial each other (r2 dials the seed r1, and
r1 is told to dial r2), with leases of ``leases`` ms (r1's, r2's; 2 s and
20 s split it here), and an application on each (so each hears periodic
reports). Once the team is whole, the TCP connections between r1 and r2 are
black-holed and new ones pass: in each robot's namespace an HTB class of 8
bit/s on ``eth0``, and u32 filters sending exactly those connections'
packets into it (this kernel has no iptables, prio, netem nor gact). Then,
for ``watch`` seconds, it records which node warned that a teammate is heard
one way only (``ramps.core.oneway``) and which exited; a node that exits
(``restart_when_split``) is started again as its supervisor would
(``Testbed.restart``). At the end: whether the team is whole, and whether a
program from each robot's application runs. A split comes in some tries
only (2 of 5 here): run several.
"""

from __future__ import annotations

import subprocess
import time
from typing import Any, Callable

SLOW_CLASS = "1:20"


def established(ns: str, peer_ip: str) -> list[tuple[str, str, str, str]]:
    """The established TCP connections of namespace ``ns`` with ``peer_ip``:
    (local ip, local port, peer ip, peer port)."""
    out = subprocess.run(["ip", "netns", "exec", ns, "ss", "-tnH", "state", "established"],
                         capture_output=True, text=True, check=True).stdout
    return [c for c in parse_ss(out) if c[2] == peer_ip]


def parse_ss(text: str) -> list[tuple[str, str, str, str]]:
    """(local ip, local port, peer ip, peer port) of each line of ``ss -tnH`` (IPv4)."""
    conns = []
    for line in text.splitlines():
        fields = line.split()
        if len(fields) < 2:
            continue
        (lip, lport), (pip, pport) = (f.rsplit(":", 1) for f in fields[-2:])
        conns.append((lip, lport, pip, pport))
    return conns


def black_hole(nss: dict[str, str], conns: list[tuple[str, str, str, str]]) -> None:
    """Send the packets of ``conns`` (seen from r2: r2's side first) into an 8 bit/s class,
    in both robots' namespaces (``nss``: robot -> namespace); every other packet passes."""
    from ramps.testbed.net import run_in

    def tc(robot: str, *args: str) -> None:
        run_in(["tc", *args], nss[robot])

    for robot in ("r1", "r2"):
        tc(robot, "qdisc", "add", "dev", "eth0", "root", "handle", "1:", "htb", "default", "10")
        tc(robot, "class", "add", "dev", "eth0", "parent", "1:", "classid", "1:10", "htb", "rate", "10gbit")
        tc(robot, "class", "add", "dev", "eth0", "parent", "1:", "classid", SLOW_CLASS, "htb", "rate", "8bit",
           "ceil", "8bit")
    for lip, lport, pip, pport in conns:
        for robot, dst, sport, dport in (("r2", pip, lport, pport), ("r1", lip, pport, lport)):
            tc(robot, "filter", "add", "dev", "eth0", "parent", "1:", "protocol", "ip", "prio", "1", "u32",
               "match", "ip", "dst", f"{dst}/32", "match", "ip", "sport", sport, "0xffff",
               "match", "ip", "dport", dport, "0xffff", "flowid", SLOW_CLASS)


def run_split(*, restart: bool, leases: tuple[int, int] = (2000, 20000), watch: float = 90.0,
              log: Callable[[str], None] | None = None) -> dict[str, Any]:
    """One try (module docstring); the figures as a dict."""
    from ramps.testbed import Testbed, net
    from ramps.testbed.bed import DidNotJoin

    log = log or (lambda _m: None)
    x = net.free_subnet()
    r2_ip = net.robot_ip(x, 2)
    cfg: dict[str, dict[str, Any]] = {"r1": {"connect": [f"tcp/{r2_ip}:7447"], "lease_ms": leases[0], "restart_when_split": restart},
           "r2": {"lease_ms": leases[1], "restart_when_split": restart}}
    out: dict[str, Any] = {"restart_when_split": restart, "leases_ms": list(leases)}
    with Testbed(2, cores=2, discovery="connect", robot_config=cfg) as tb:
        if tb.robots["r2"]["ip"] != r2_ip:
            raise RuntimeError(f"another testbed took subnet {x} meanwhile: try again")
        tb.wait_alive()
        with tb.client("r1") as a1, tb.client("r2") as a2:
            for app in (a1, a2):
                app.submit("noop").result(timeout=30)
            time.sleep(3)
            nss = {r: tb.robots[r]["ns"] for r in ("r1", "r2")}
            conns = established(nss["r2"], tb.robots["r1"]["ip"])
            black_hole(nss, conns)
            out["connections_black_holed"] = len(conns)
            log(f"black-holed {len(conns)} connections between r1 and r2")
            out["events"] = _watch(tb, watch, log)
            try:
                out["team_whole_after_s"] = round(tb.wait_alive(timeout=20), 1)
                for app in (a1, a2):  # raises if a program from either robot does not run
                    app.submit("noop").result(timeout=30)
                out["ran_after"] = True
            except DidNotJoin as exc:
                out["split"] = str(exc).splitlines()[0]
    return out


def _watch(tb: Any, watch: float, log: Callable[[str], None]) -> list[list[Any]]:
    """[seconds after the cut, robot, what] for each warning, exit and restart seen."""
    t0 = time.monotonic()
    events: list[list[Any]] = []

    def seen(robot: str, what: str) -> bool:
        return any(e[1] == robot and e[2].startswith(what) for e in events)

    while time.monotonic() - t0 < watch:
        time.sleep(2)
        for r in ("r1", "r2"):
            if "heard one way only" in tb.log_tail(r) and not seen(r, "warned"):
                events.append([round(time.monotonic() - t0, 1), r, "warned"])
                log(f"{events[-1][0]} s: {r} warned")
            if tb.process_state(r) == "dead" and not seen(r, "exited"):
                p = tb.procs.popen.get(tb.procs.record(r)["pid"])
                events.append([round(time.monotonic() - t0, 1), r, f"exited {p.poll() if p else '?'}"])
                took = tb.restart(r, timeout=30)  # what its supervisor does
                events.append([round(time.monotonic() - t0, 1), r, f"restarted: back in {took:.1f} s"])
                log(f"{events[-1][0]} s: {r} exited and was restarted")
        if seen("r1", "restarted") or seen("r2", "restarted"):
            break
    return events
