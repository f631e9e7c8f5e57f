"""When a host's silence is a failure: the origin's timeouts around its own stalls.

How this works: an origin writes a host off when it does not accept an
offer within ``connect_timeout`` or a running program's heartbeats stop for
``heartbeat_timeout`` (``ramps.core.timers``). When this robot's own driver
stalled (``stalled``: the seconds taken out of the core's clock, and the
wake), what its hosts sent meanwhile is still on its way in, read by a node
that runs again at the pace it was starved at: a host's silence counts
only from the wake plus the stall's length (at most a heartbeat timeout),
so a stall of the origin's never writes off a healthy host (issue 23).
After a stall that may have closed links, ``ramps.core.relink`` says which
hosts' links are not back: their timeouts wait for the link, and once it is
back (``relinked``) count from that moment. An offer the driver sends
whole on a thread of its own (a large one, ``sending``) cannot be accepted
before its last byte is out, however slow the link and however stale the
origin's estimate of it: its connect timeout waits until the driver is
through with it, and counts from then. ``held_off`` sets a due timeout
again for later when any of this says it is too early.

Fleets: an origin with programs on more than ``placement_sample`` hosts sets
those heartbeat timeouts again on a grid of ``heartbeat_period`` (up to one
period later), so its thousands of programs' timers fall due together, one
wake for many, instead of one wake each.

Rules: functions of the origin they act for, which they see as a
``SilentOrigin``; no clock (``now`` comes in), no I/O.
"""

from __future__ import annotations

import math
from typing import Protocol

from ramps.core.config import RampsConfig
from ramps.core.program import AutonomousProgram, Event, ProgramState
from ramps.core.relink import Relink
from ramps.core.timers import Timers

S = ProgramState
E = Event


class SilentOrigin(Protocol):
    """What the silence rules read and change of ``ramps.core.origin.Origin``."""

    config: RampsConfig
    relink: Relink
    timers: Timers
    programs: dict[str, AutonomousProgram]
    #: host -> the ids of its live programs, in placement order
    by_host: dict[str, dict[str, None]]
    #: this robot's stalls: their seconds in all, the latest wake, and the
    #: grace after it before a host's silence counts
    stalled_s: float
    woke_at: float
    wake_grace: float


def stalled(origin: SilentOrigin, seconds: float, now: float, *, links: bool) -> None:
    """This robot's driver did not run for ``seconds`` and woke at ``now``
    (``links``: long enough that its links may have closed: relink instead)."""
    seconds = max(0.0, seconds)
    origin.stalled_s += seconds
    origin.woke_at = now
    origin.wake_grace = 0.0 if links else min(seconds, origin.config.heartbeat_timeout)


def sending(origin: SilentOrigin, program_id: str, attempt: int, done: bool, now: float) -> None:
    """The driver sends ``program_id``'s offer of ``attempt`` whole
    (``done`` False), or is through with it (True): from then, its host has
    ``connect_timeout`` to accept it."""
    ap = origin.programs.get(program_id)
    if ap is None:
        return
    if not done:
        ap.sending = attempt
        return
    if ap.sending != attempt:
        return
    ap.sending = 0
    if ap.attempt == attempt and ap.timer == E.CONNECT_TIMEOUT and ap.deadline is not None:
        origin.timers.set(ap, max(ap.deadline, now + origin.config.connect_timeout), ap.timer)


def held_off(origin: SilentOrigin, ap: AutonomousProgram, kind: Event, now: float) -> bool:
    """Whether ``ap``'s due timer ``kind`` waits on (set again for later): its
    host's link is not back since this robot's stall, or the silence counts
    from this robot's wake and has not lasted long enough."""
    config, timers = origin.config, origin.timers
    if kind == E.CONNECT_TIMEOUT and ap.sending and ap.sending == ap.attempt:
        timers.set(ap, now + config.connect_timeout, kind)  # its offer is still on its way out
        return True
    if origin.relink.waiting(ap.host, now) and kind in (E.HEARTBEAT_TIMEOUT, E.CONNECT_TIMEOUT):
        timers.set(ap, origin.relink.until, kind)  # its link is not back since this robot stalled
        return True
    heard_from = origin.woke_at + origin.wake_grace  # after this robot's stall
    if kind == E.CONNECT_TIMEOUT and heard_from + config.connect_timeout > now:
        # this robot stalled meanwhile: the acceptance may be behind the stall
        timers.set(ap, heard_from + config.connect_timeout, kind)
        return True
    if kind == E.HEARTBEAT_TIMEOUT:
        # silence counts from the last word of the host, or from this
        # robot's latest stall, whichever is later
        due = max(ap.last_heard, heard_from) + config.heartbeat_timeout
        if due > now:  # heard from the host since the timer was set, or this robot stalled
            if 0 < config.placement_sample < len(origin.by_host):  # a fleet: see the module docstring
                due = math.ceil(due / config.heartbeat_period) * config.heartbeat_period
            timers.set(ap, due, kind)
            return True
    return False


def relinked(origin: SilentOrigin, host: str, now: float) -> None:
    """``host``'s link is back after this robot's stall: its silence counts
    from now, for a heartbeat or a connect timeout."""
    for pid in origin.by_host.get(host, ()):
        ap = origin.programs[pid]
        if ap.host == host and ap.state in (S.OFFERED, S.RUNNING) and ap.deadline is not None:
            ap.last_heard = max(ap.last_heard, now)
            if ap.timer == E.CONNECT_TIMEOUT:
                origin.timers.set(ap, max(ap.deadline, now + origin.config.connect_timeout), ap.timer)
