"""How fast the team notices a fault, measured on the testbed.

How this works: a plain Zenoh session in the root namespace, connected to
every robot over the bridge, subscribes to the liveliness tokens
``ramps/<team>/alive/*`` (one per node). ``detection_time`` injects a fault
(``crash``, ``cut`` or ``freeze``) on one robot and times the token's
DELETE; then it recovers the robot and times the token's PUT (rejoin). The
lease that counts is the one the *faulty* node announces (``--lease-ms``).

    python -m ramps.lab.detect --robots 3 --trials 5            # node default lease
    python -m ramps.lab.detect --robots 3 --trials 5 --lease-ms 1000

Measured here (2-core VM, cgroup v1, 3 robots at 0.667 host cores each,
eclipse-zenoh 1.10, discovery multicast + seed; median [min-max] of 5):

================  =====================  ===================
fault             default lease 2000 ms  --lease-ms 1000
================  =====================  ===================
crash (SIGKILL)   6 ms [5-8]             6 ms [6-8]
cut (link down)   2001 ms [2001-2001]    1001 ms [984-1004]
freeze (SIGSTOP)  1999 ms [1501-2001]    752 ms [750-1000]
================  =====================  ===================

Rejoin after ``recover`` (token PUT seen again), same runs: after a crash
~0.99 s (0.99-1.13; a new node process starts, imports, measures its speed
under its quota and declares its token); after a cut ~1.0 s (1.0-1.36; the
seed's redial period); after a freeze 8 ms typically (6-11), ~1 s when the
thawed node had to redial. So ``--lease-ms`` bounds cut and freeze detection
(a cut is noticed at almost exactly one lease, a freeze at 0.75-1 lease),
and a crash is noticed in milliseconds whatever the lease.

False alarms on a poor link (``--flap``): r3 of 3 robots gets random packet
loss both ways (iptables ``statistic`` match in its namespace; this kernel
has no netem), plain or with silent gaps of 0.1-1.0 s every 2-6 s (WiFi
roaming, a robot behind a shelf, 6-7 s of silence per minute). False
liveliness DELETEs of r3 in 60 s each (one sample per cell; 2-core VM):

==========  ====  ==========  ====  ==========  ====  ==========
lease (ms)  10%   10% + gaps  20%   20% + gaps  30%   30% + gaps
==========  ====  ==========  ====  ==========  ====  ==========
1000        0     4           0     3           1     5
1500        0     4           1     2           0     1
1800        0     2           0     0           1     1
2000        0     0           0     0           0     4
==========  ====  ==========  ====  ==========  ====  ==========

Loss alone hardly matters (TCP retransmits; keep-alives arrive late, not
never), but a sub-second gap plus retransmission back-off (RTO doubling from
200 ms) silences a link for up to ~1.8 s, which trips leases below 2 s. So
the node's default lease is 2000 ms: no false alarm up to 20% loss with
gaps, at the price of noticing a cut or freeze after 1.5-2 s (heartbeats
every 0.5 s with a 2 s timeout usually notice a busy host a little sooner).
A wired team can take ``--lease-ms 1000``.

Why: a crash closes the TCP connections at once (the kernel resets them); a
cut or frozen robot says nothing and is declared gone when its lease runs
out without keep-alives (sent 4 times per lease). "Default" is the node's
own default, ``NodeSettings.lease_ms`` = 2000 ms, not Zenoh's 10 s.
"""

from __future__ import annotations

import argparse
import statistics
import time
from typing import TYPE_CHECKING

from ramps.testbed.bed import watch_team

if TYPE_CHECKING:
    from ramps.runtime.watch import TeamWatcher


def detection_time(testbed, watcher: TeamWatcher, robot: str, fault: str, *, timeout: float = 30.0,
                   rejoin: bool = True) -> tuple[float | None, float | None]:
    """(seconds until the DELETE, seconds from recover until the PUT again)."""
    if watcher.wait(robot, True, timeout) is None:
        raise RuntimeError(f"robot {robot} is not alive before the fault")
    t0 = time.monotonic()
    getattr(testbed, fault)(robot)
    gone = watcher.wait(robot, False, timeout, since=t0)
    back = None
    if rejoin:
        t1 = time.monotonic()
        testbed.recover(robot, wait=False)
        seen = watcher.wait(robot, True, timeout, since=t1)
        back = None if seen is None else seen - t1
        testbed.wait_alive(timeout=timeout)
    return (None if gone is None else gone - t0), back


def flapping(testbed, watcher: TeamWatcher, robot: str, *, loss: float, duration: float,
             outages: tuple[float, float] | None = None, seed: int = 0) -> dict:
    """False alarms on a poor but working link: for ``duration`` seconds every
    packet of ``robot`` is dropped with probability ``loss``, and with
    ``outages=(lo, hi)`` the link also goes fully silent for a random
    lo..hi seconds every 2-6 s (WiFi roaming or a robot driving behind a
    shelf). Returns the liveliness DELETEs of that robot seen meanwhile: a
    DELETE is a false detection, since the robot never failed."""
    import random

    rng = random.Random(seed)
    if watcher.wait(robot, True, 30.0) is None:
        raise RuntimeError(f"robot {robot} is not alive before the test")
    t0 = time.monotonic()
    end = t0 + duration
    silent = 0.0
    testbed.lossy(robot, loss)
    try:
        while (now := time.monotonic()) < end:
            if outages is None:
                time.sleep(min(1.0, end - now))
                continue
            time.sleep(min(rng.uniform(2.0, 6.0), max(0.0, end - now)))
            if time.monotonic() >= end:
                break
            gap = rng.uniform(*outages)
            testbed.lossy(robot, 1.0)
            time.sleep(gap)
            silent += gap
            testbed.lossy(robot, loss)
    finally:
        testbed.lossy(robot, 0)
    with watcher.cv:
        dels = [t - t0 for t, r, put in watcher.events if r == robot and not put and t0 <= t <= end]
    watcher.wait(robot, True, 30.0)
    return dict(robot=robot, loss=loss, outages=outages, duration=duration, silent=round(silent, 2),
                false_detections=len(dels), at=[round(t, 2) for t in dels])


def _outages(text: str) -> tuple[float, float] | None:
    """``--outages``: ``lo,hi`` seconds, or '' for none."""
    if not text:
        return None
    want = f"want lo,hi seconds with 0 <= lo <= hi, got {text!r}"
    try:
        parts = [float(x) for x in text.split(",")]
    except ValueError:
        raise argparse.ArgumentTypeError(want) from None
    if len(parts) != 2 or not 0 <= parts[0] <= parts[1]:
        raise argparse.ArgumentTypeError(want)
    return parts[0], parts[1]


def main(argv: list[str] | None = None) -> None:
    from ramps.testbed import Testbed

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--robots", type=int, default=3)
    ap.add_argument("--trials", type=int, default=5)
    ap.add_argument("--lease-ms", type=int, default=None)
    ap.add_argument("--faults", default="crash,cut,freeze")
    ap.add_argument("--flap", action="store_true",
                    help="measure false detections on a lossy link instead of detection times")
    ap.add_argument("--loss", default="0.1,0.2,0.3", help="with --flap: packet loss rates to try")
    ap.add_argument("--outages", type=_outages, default="0.1,1.0",
                    help="with --flap: also silent gaps of lo,hi s ('' for none)")
    ap.add_argument("--duration", type=float, default=60.0, help="with --flap: seconds per loss rate")
    ap.add_argument("--json", default=None, help="with --flap: save the results to this file")
    a = ap.parse_args(argv)
    if a.flap:
        import json

        outages: tuple[float, float] | None = a.outages
        results = []
        with Testbed(a.robots, lease_ms=a.lease_ms) as tb, watch_team(tb) as w:
            for i, loss in enumerate(float(x) for x in a.loss.split(",")):
                for gaps in ([None, outages] if outages else [None]):
                    r = flapping(tb, w, tb.names[-1], loss=loss, duration=a.duration, outages=gaps, seed=i)
                    r["lease_ms"] = a.lease_ms or "default"
                    results.append(r)
                    print(f"lease {r['lease_ms']} loss {loss:.0%} outages {gaps or '-'}: "
                          f"{r['false_detections']} false detections in {a.duration:g} s "
                          f"(silent {r['silent']} s) at {r['at']}", flush=True)
        if a.json:
            with open(a.json, "w") as f:
                json.dump(results, f, indent=1)
        return
    with Testbed(a.robots, lease_ms=a.lease_ms) as tb, watch_team(tb) as w:
        for fault in a.faults.split(","):
            gone, back = [], []
            for i in range(a.trials):
                robot = tb.names[1 + i % (len(tb.names) - 1)]
                g, b = detection_time(tb, w, robot, fault)
                gone.append(g)
                back.append(b)
            fmt = lambda xs: (f"{statistics.median(xs) * 1000:.0f} ms [{min(xs) * 1000:.0f}-{max(xs) * 1000:.0f}]"
                              if xs and None not in xs else f"missed: {xs}")
            print(f"lease {a.lease_ms or 'default'} {fault:7s} detected {fmt(gone)}  rejoin {fmt(back)}", flush=True)


if __name__ == "__main__":
    main()
