"""The testbed's network: one namespace per robot on one Linux bridge.

How this works::

    root namespace                         namespace ramps-<tb>-r1
    bridge rb-<tb> 10.201.X.254/24 ---- rb-<tb>-r1 <=veth=> eth0 10.201.X.1/24
                                   ---- rb-<tb>-r2 <=veth=> eth0 10.201.X.2/24   (ramps-<tb>-r2)
                                   ...

* A testbed id ``tb`` is ``t<X>``; X (1-250) picks the private subnet
  ``10.201.X.0/24``. ``free_subnet()`` takes the lowest X whose bridge does
  not exist and whose subnet no address or route on this host touches, so
  two testbeds (or a host that uses 10.201.X) never collide.
* Robot i (counting from 1) has ``10.201.X.i``; the bridge has ``.254`` so
  a process in the root namespace (a client, a test) reaches every robot.
  Forwarding is not turned on: robots reach each other and the root
  namespace's bridge address, nothing else.
* Multicast works across the bridge: every link has ``multicast on``, the
  bridge's IGMP snooping is off (so 224.0.0.224:7446, Zenoh scouting, is
  flooded to every port), and each namespace routes ``224.0.0.0/4`` to its
  ``eth0``. ``link_up`` puts that route back, because Linux drops manually
  added routes of a link that goes down.
* ``cut`` is ``ip link set eth0 down`` *inside* the robot's namespace: the
  robot's processes keep running, its sockets stay open, nothing gets
  through (the paper's "switching off the network card").

Rules: interface names are at most 15 characters, so robot names are short
(``check_names``). Everything is named ``ramps-*`` (namespaces) or ``rb-*``
(bridge, root ends of the veths), and ``sweep()`` removes every such thing,
whoever left it. Deleting a namespace deletes its veth pair too. Every
function here needs root; callers check ``need_root()`` first.
"""

from __future__ import annotations

import ipaddress
import os
import re
import shutil
import subprocess
from collections.abc import Set
from pathlib import Path

SUBNET_BASE = "10.201"
NS_PREFIX = "ramps-"
LINK_PREFIX = "rb-"
NETNS_DIR = Path("/run/netns")
IFNAMSIZ = 15


class NetError(RuntimeError):
    """An ``ip`` command failed."""


def need_root(what: str = "the testbed") -> None:
    """Raise ``PermissionError`` before anything is created when we cannot."""
    if os.geteuid() != 0:
        raise PermissionError(f"{what} needs root: it creates network namespaces, a bridge and cpu cgroups "
                              "(run as root, e.g. `sudo ramps testbed up`)")
    if shutil.which("ip") is None:
        raise PermissionError(f"{what} needs the `ip` command (iproute2)")
    if shutil.which("nsenter") is None:
        raise PermissionError(f"{what} needs the `nsenter` command (util-linux)")


def ip(*args: str, ns: str | None = None, check: bool = True) -> str:
    cmd = ["ip", *(["-n", ns] if ns else []), *args]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if check and r.returncode != 0:
        raise NetError(f"`{' '.join(cmd)}` failed: {r.stderr.strip() or r.stdout.strip()}")
    return r.stdout


# ------------------------------------------------------------------ names
def ns_name(tb: str, robot: str) -> str:
    return f"{NS_PREFIX}{tb}-{robot}"


def bridge_name(tb: str) -> str:
    return f"{LINK_PREFIX}{tb}"


def veth_name(tb: str, robot: str) -> str:
    """Root end of robot's veth; inside its namespace the other end is eth0."""
    return f"{LINK_PREFIX}{tb}-{robot}"


def robot_ip(x: int, index: int) -> str:
    return f"{SUBNET_BASE}.{x}.{index}"


def bridge_ip(x: int) -> str:
    return f"{SUBNET_BASE}.{x}.254"


def check_names(tb: str, robots: list[str]) -> None:
    if len(robots) > 250:
        raise ValueError("a testbed has at most 250 robots")
    for r in robots:
        if not re.fullmatch(r"[A-Za-z0-9_]{1,8}", r):
            raise ValueError(f"robot name {r!r} must be 1-8 letters, digits or '_' (it names network interfaces)")
        if len(veth_name(tb, r)) > IFNAMSIZ:
            raise ValueError(f"robot name {r!r} is too long: interface {veth_name(tb, r)!r} has more than "
                             f"{IFNAMSIZ} characters")
    if len(set(robots)) != len(robots):
        raise ValueError("robot names must be different")


# ------------------------------------------------------------------ looking
def namespaces() -> list[str]:
    out = ip("netns", "list", check=False)
    return [line.split()[0] for line in out.splitlines() if line.strip()]


def links(ns: str | None = None) -> dict[str, str]:
    """name -> 'up' or 'down' (administrative state)."""
    out = ip("-o", "link", "show", ns=ns, check=False)
    res = {}
    for line in out.splitlines():
        m = re.match(r"\d+: ([^:@]+)(?:@[^:]+)?: <([^>]*)>", line)
        if m:
            res[m.group(1)] = "up" if "UP" in m.group(2).split(",") else "down"
    return res


def link_state(ns: str, dev: str = "eth0") -> str:
    """'up', 'down' (administratively), or 'missing'."""
    out = ip("-o", "link", "show", "dev", dev, ns=ns, check=False)
    if not out:
        return "missing"
    m = re.search(r"<([^>]*)>", out)
    return "up" if m and "UP" in m.group(1).split(",") else "down"


def _subnet_used(x: int) -> bool:
    net = ipaddress.ip_network(f"{SUBNET_BASE}.{x}.0/24")
    out = ip("-o", "-4", "addr", "show", check=False) + ip("-4", "route", "show", "table", "all", check=False)
    for tok in re.findall(r"(\d+\.\d+\.\d+\.\d+(?:/\d+)?)", out):
        try:
            other = ipaddress.ip_network(tok, strict=False)
        except ValueError:
            continue
        if other.prefixlen > 0 and net.overlaps(other):
            return True
    return False


def free_subnet(taken: Set[int] = frozenset()) -> int:
    """The lowest X in 1..250 free for a new testbed ``t<X>``."""
    existing = set(links())
    for x in range(1, 251):
        if x in taken or bridge_name(f"t{x}") in existing or _subnet_used(x):
            continue
        return x
    raise NetError(f"no free {SUBNET_BASE}.X.0/24 subnet for a testbed")


# ------------------------------------------------------------------ building
def make_bridge(tb: str, x: int) -> None:
    br = bridge_name(tb)
    ip("link", "add", br, "type", "bridge", "mcast_snooping", "0")
    ip("addr", "add", f"{bridge_ip(x)}/24", "dev", br)
    ip("link", "set", br, "multicast", "on", "up")


def make_robot(tb: str, x: int, index: int, robot: str) -> None:
    """Namespace, veth pair on the bridge, address, loopback and multicast route."""
    ns, veth = ns_name(tb, robot), veth_name(tb, robot)
    peer = f"{LINK_PREFIX}{tb}-{robot}p"[:IFNAMSIZ]
    ip("netns", "add", ns)
    ip("link", "add", veth, "type", "veth", "peer", "name", peer)
    ip("link", "set", peer, "netns", ns)
    ip("link", "set", veth, "master", bridge_name(tb), "multicast", "on", "up")
    ip("link", "set", peer, "name", "eth0", ns=ns)
    ip("addr", "add", f"{robot_ip(x, index)}/24", "dev", "eth0", ns=ns)
    ip("link", "set", "lo", "up", ns=ns)
    link_up(ns)


def link_up(ns: str) -> None:
    ip("link", "set", "eth0", "multicast", "on", "up", ns=ns)
    ip("route", "replace", "224.0.0.0/4", "dev", "eth0", ns=ns)


def link_down(ns: str) -> None:
    ip("link", "set", "eth0", "down", ns=ns)


def set_loss(ns: str, loss: float) -> None:
    """Drop each packet in and out of the namespace with probability ``loss``
    (0 removes the rule). Uses iptables' ``statistic`` match inside the
    namespace, because this kernel has no netem; the rules die with the
    namespace, so nothing is left behind."""
    if not 0 <= loss <= 1:
        raise ValueError(f"loss must be in [0, 1], got {loss}")
    exe = shutil.which("iptables")
    if exe is None:
        raise NetError("packet loss needs iptables (apt-get install iptables)")
    for chain in ("INPUT", "OUTPUT"):
        run_in([exe, "-w", "-F", chain], ns)
        if loss > 0:
            run_in([exe, "-w", "-A", chain, "-m", "statistic", "--mode", "random",
                  "--probability", f"{loss:.4f}", "-j", "DROP"], ns)


def run_in(argv: list[str], ns: str) -> None:
    """Run ``argv`` in namespace ``ns``; NetError with its stderr if it fails."""
    r = subprocess.run(["nsenter", f"--net={NETNS_DIR / ns}", *argv], capture_output=True, text=True)
    if r.returncode != 0:
        raise NetError(f"{' '.join(argv)} in {ns} failed: {r.stderr.strip()}")


def remove(tb: str, robots: list[str]) -> None:
    """Delete the namespaces (and with them the veths), then the bridge."""
    have_ns = set(namespaces())
    for r in robots:
        if ns_name(tb, r) in have_ns:
            ip("netns", "delete", ns_name(tb, r), check=False)
    have = links()
    for r in robots:
        if veth_name(tb, r) in have:
            ip("link", "delete", veth_name(tb, r), check=False)
    if bridge_name(tb) in have:
        ip("link", "delete", bridge_name(tb), check=False)


def sweep() -> list[str]:
    """Remove every ``ramps-*`` namespace and ``rb-*`` link; return what went."""
    gone = []
    for ns in namespaces():
        if ns.startswith(NS_PREFIX):
            ip("netns", "delete", ns, check=False)
            gone.append(f"namespace {ns}")
    have = links()
    for name in sorted(have, key=lambda n: -n.count("-")):  # veths (two dashes) before bridges
        if name.startswith(LINK_PREFIX) and name in links():
            ip("link", "delete", name, check=False)
            gone.append(f"link {name}")
    return gone


def netns_pids(ns: str) -> list[int]:
    out = ip("netns", "pids", ns, check=False)
    return [int(p) for p in out.split() if p.isdigit()]
