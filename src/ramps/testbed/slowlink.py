"""Slow links on the testbed, and ``crunch``, a program whose parameters cross them.

How this works: ``tbf`` slows a device's egress to ``rate`` bytes/s with a
token-bucket filter (``tc qdisc ... tbf``); ``slow_link`` slows both
directions of a robot's link, on both ends of its veth: the robot's ``eth0``
inside its namespace (what it sends) and the bridge port in the root
namespace (what it receives). This kernel has no ``netem``, so a link's
*delay* cannot be added; ``tbf`` is what it offers to slow a link. The rules
die with the namespace and the veth. ``ramps.testbed.sites`` slows the
routers' link with ``tbf`` too.

``crunch`` burns ``units`` of work on parameters of ``len(data)`` bytes and
returns their size: programs of a chosen size on the wire and a chosen
amount of work. A testbed registers it on its nodes with
``programs=[TARGET]`` (the sites do by default). The experiment on a slow
link (``ramps testbed experiment slow-link``) is ``ramps.lab.slowlink``.
"""

from __future__ import annotations

import shutil
import subprocess
from typing import Any

import ramps
from ramps.programs.burn import burn
from ramps.testbed.net import NETNS_DIR, NetError

#: register in the client's process as well as on the nodes (``--program``)
TARGET = "ramps.testbed.slowlink:crunch"


@ramps.program(work=0.3)
def crunch(data: bytes = b"", units: float = 0.3) -> dict[str, Any]:
    """Burn ``units`` of work on parameters of ``len(data)`` bytes; return their size."""
    burn(units=units)
    return {"bytes": len(data)}



def tbf(dev: str, rate: float, ns: str | None = None) -> None:
    """Slow ``dev``'s egress to ``rate`` bytes/s (a token bucket of 4 KiB, at
    most 0.5 s of queue), inside namespace ``ns`` when given."""
    exe = shutil.which("tc")
    if exe is None:
        raise NetError("slowing a link needs tc (apt-get install iproute2)")
    argv = [exe, "qdisc", "replace", "dev", dev, "root", "tbf", "rate", f"{int(rate * 8)}bit", "burst", "4096",
            "latency", "500ms"]
    if ns is not None:
        argv = ["nsenter", f"--net={NETNS_DIR / ns}", *argv]
    r = subprocess.run(argv, capture_output=True, text=True)
    if r.returncode != 0:
        raise NetError(f"{' '.join(argv)} failed: {r.stderr.strip()}")


def slow_link(tb, robot: str, rate: float) -> None:
    """Both directions of ``robot``'s link at ``rate`` bytes/s."""
    rb = tb.robots[robot]
    tbf("eth0", rate, ns=rb["ns"])
    tbf(rb["veth"], rate)
