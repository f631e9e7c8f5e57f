"""A node's core clock: the time its driver was awake, stalls taken out.

How this works: ``AwakeClock`` is a part of the node's driver
(``ramps.runtime.node``). The driver reads the core's time from it
(``read``) and says how long it allows itself to sleep (``sleep_until``).
A stall is a reading later than the driver allowed itself to be
(``sleep_until``, or the previous reading) by more than ``STALL_MIN``: the
process was frozen (SIGSTOP), starved of CPU on a busy robot, or paused in
a long collection. Nothing could be heard meanwhile, so the core must not
count that time as silence from its hosts (it would write off healthy
programs, its own included, the moment the node wakes): the stall is taken
out of the core's time. Deadlines stay as long in the time the node was
awake to hear. Each stall is told to the core once (``told``: a
``Stalled`` event), saying whether it was long enough, as a fraction of the
Zenoh lease, to have let teammates' links to this node close. Teammates
whose liveliness went just after a stall are held a moment (``HeldLosses``):
it may be only their lease on this stalled node that ran out.
"""

from __future__ import annotations

import logging

from ramps.core.relink import Stalled
from ramps.runtime.node_trace import NodeTrace
from ramps.runtime.transport import Clock

log = logging.getLogger("ramps.node")
#: a driver that wakes this much later than it allowed itself was stalled
STALL_MIN = 0.5
#: a stall this long, as a fraction of the Zenoh lease, may have let
#: teammates' leases on this node run out and their links close (Zenoh sends
#: keep-alives every quarter lease): the core is told (``Stalled``), so it
#: waits for their links before counting silence
RELINK_LEASE_FRACTION = 0.75


class AwakeClock:
    """The core's clock of robot ``robot``'s node, on ``clock``'s monotonic
    time, for a Zenoh lease of ``lease_s`` seconds; stalls go to ``trace``."""

    def __init__(self, clock: Clock, *, lease_s: float, robot: str, trace: NodeTrace) -> None:
        self.clock = clock
        self.robot = robot
        self.trace = trace
        #: the driver's stalls: how many, seconds in all, and the monotonic time the last ended
        self.stalls = 0
        self.stalled_s = 0.0
        self.stalled_at = 0.0
        #: seconds taken out of the core's time
        self.offset = 0.0
        #: stalls not yet told to the core (seconds), and whether one was long enough to close links
        self.pending = 0.0
        self.links = False
        self.relink_after = lease_s * RELINK_LEASE_FRACTION
        #: the monotonic time of the last reading, and until when the driver allowed itself to sleep
        self.last_read = 0.0
        self.sleep_until = 0.0

    def start(self) -> float:
        """The core's time at start (no stall before it)."""
        self.last_read = self.clock.monotonic()
        return self.read()

    def read(self) -> float:
        """The core's time now: monotonic time less every stall of this node."""
        t = self.clock.monotonic()
        late = t - max(self.last_read, self.sleep_until)
        if late > STALL_MIN:
            self.offset += late
            self.stalls += 1
            self.stalled_s += late
            self.stalled_at = t
            self.pending += late
            if late >= self.relink_after:
                self.links = True
            self.trace.write("stalled", "", "", 0, f"{late:.3f}", at=t)
            log.warning("node %s: driver stalled for %.1f s (frozen, starved of CPU or paused); "
                        "that time does not count as silence from teammates", self.robot, late)
        self.last_read = t
        self.sleep_until = 0.0
        return t - self.offset

    def now(self) -> float:
        """The core's time now without a reading (no stall is noticed): for
        what is due a moment from now (a held update, metrics' latencies)."""
        return self.clock.monotonic() - self.offset

    def sleep(self, seconds: float) -> None:
        """The driver sleeps ``seconds`` from now: waking later is a stall."""
        self.sleep_until = self.clock.monotonic() + seconds

    def since_stall(self, seconds: float) -> bool:
        """Whether this node stalled within the last ``seconds``."""
        return bool(self.stalled_at) and self.clock.monotonic() - self.stalled_at < seconds

    def told(self) -> Stalled:
        """The stalls not yet told to the core, as its event (then none are pending)."""
        seconds, self.pending = self.pending, 0.0
        links, self.links = self.links, False
        return Stalled(seconds=seconds, links=links)


class HeldLosses:
    """Teammates whose liveliness went just after this node stalled (``awake``), held ``grace`` seconds.

    Just after a stall, every teammate's lease on this node may have run
    out: their links close and their tokens vanish, then come back as soon
    as Zenoh reconnects. Such a loss is held and forgotten if the robot
    comes back meanwhile; a robot that does not is lost when it falls due."""

    def __init__(self, awake: AwakeClock, grace: float) -> None:
        self.awake = awake
        self.grace = grace
        #: robot -> the core's time it counts as lost
        self.held: dict[str, float] = {}

    def lost(self, robot: str, now: float) -> bool:
        """``robot``'s token went at the core's time ``now``: whether the core hears it now (else it is held)."""
        if self.awake.since_stall(self.grace):
            self.held[robot] = now + self.grace
            return False
        return True

    def back(self, robot: str) -> bool:
        """``robot``'s token came: whether its loss was held (lost and back during the grace)."""
        return self.held.pop(robot, None) is not None

    def forget(self, robot: str) -> None:
        self.held.pop(robot, None)

    def next_due(self) -> float:
        """The core's time the next held loss falls due (inf: none held)."""
        return min(self.held.values(), default=float("inf"))

    def due(self, now: float) -> list[str]:
        """The robots whose held loss falls due by the core's time ``now`` (no longer held)."""
        robots = [robot for robot, when in self.held.items() if when <= now]
        for robot in robots:
            del self.held[robot]
        return robots
