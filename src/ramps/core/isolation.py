"""Isolation: when the robot cut off was this one, not the hosts it wrote off.

How this works: when a teammate's session goes (``host_lost``) or it falls
silent (``heartbeat_timeout``), the origin writes off the attempt it ran
(``AutonomousProgram.written_off``), places the program again, and tells
``Isolation.wrote_off``, which keeps the program as revivable. If every
teammate then falls silent at once (``LoadView.isolated``), it was this
robot that was cut off, and the hosts lost a moment earlier (their leases
ran out one by one, or their heartbeats timed out first) were not at fault:
``revive`` wants the results of the copies written off within ``window``
again (``AutonomousProgram.live``), beside the run that replaced them; the
first result wins. ``due`` tells the origin's ``next_deadline`` when that
silence would show; at a ``tick`` past the window, programs too old to be
explained by an isolation are no longer revivable.

A copy written off is not forgotten where the origin was not cut off
either (``late``, ``RampsConfig.late_results``): its host may only have
been starved or frozen for a while. A result from it that comes before the
program ended is delivered, and a heartbeat from it makes it wanted again
(``heard_again``) beside the copy placed since.

Rules: no clock (``now`` comes in), no I/O. It shares the origin's program
table, view and configuration, and tells the origin of each program it
changes through ``changed``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

from ramps.core.config import RampsConfig
from ramps.core.events import Action, Note
from ramps.core.loadview import LoadView
from ramps.core.program import FINAL, AutonomousProgram


class Isolation:
    """The programs of one origin whose written-off copies an isolation would revive."""

    def __init__(self, me: str, view: LoadView, config: RampsConfig, programs: Mapping[str, AutonomousProgram],
                 changed: Callable[[AutonomousProgram], None]) -> None:
        self.me = me
        self.view = view
        self.config = config
        self.programs = programs
        self.changed = changed
        #: programs with a recently written-off attempt, in the order written
        #: off (a set's order would follow the process's hash seed)
        self.revivable: dict[str, None] = {}

    def wrote_off(self, ap: AutonomousProgram, attempt: int, host: str, now: float) -> None:
        """The origin gave up on ``ap``'s ``attempt`` on ``host``, lost or silent, at ``now``."""
        ap.written_off.append((attempt, host, now))
        self.revivable[ap.program_id] = None

    def late(self, ap: AutonomousProgram, attempt: int, host: str) -> bool:
        """Whether ``ap``'s ``attempt`` on ``host`` is a copy this origin wrote off
        and still wants word of (``RampsConfig.late_results``): its result is
        the program's, and a heartbeat from it makes it wanted again."""
        return self.config.late_results and ap.state not in FINAL and any(
            a == attempt and h == host for a, h, _ in ap.written_off)

    def heard_again(self, ap: AutonomousProgram, attempt: int, host: str, out: list[Action]) -> None:
        """A written-off copy (``late``) is heard from: wanted again beside the
        copy placed since, the first result wins."""
        ap.live[attempt] = host
        self.changed(ap)
        out.append(Note(what="revived", program_id=ap.program_id, robot=host, attempt=attempt,
                        detail="written off, heard from again: its copy is wanted beside the new one"))

    def window(self) -> float:
        """How long before the isolation shows a host may have been written off for it."""
        # a host is written off at most a heartbeat timeout after the cut, and
        # the cut is certain at most an isolation timeout after it
        return self.config.heartbeat_timeout + self.config.isolation_timeout + self.config.heartbeat_period

    def due(self) -> float | None:
        """When silence from every teammate would show that this robot, not
        the hosts it just wrote off, was cut off (None: nothing to revive)."""
        if not self.revivable or self.view.last_remote_report is None:
            return None
        return self.view.last_remote_report + self.config.isolation_timeout + 1e-6

    def check(self, now: float, out: list[Action]) -> None:
        """Revive the written-off copies if this robot is isolated now."""
        if self.view.isolated(now, self.config.isolation_timeout):
            self.revive(now, out)

    def tick(self, now: float, out: list[Action]) -> None:
        """Revive if isolated now; else forget revivable programs too old to be."""
        if not self.revivable:
            return
        if self.view.isolated(now, self.config.isolation_timeout):
            self.revive(now, out)
            return
        newest = max((w[2] for pid in self.revivable if (ap := self.programs.get(pid)) is not None
                      for w in ap.written_off), default=None)
        if newest is None or newest < now - self.window():
            self.revivable.clear()  # too old to be explained by an isolation now

    def revive(self, now: float, out: list[Action]) -> None:
        """Every teammate is gone at once: want the results of the copies
        written off within the window again, beside the local run."""
        horizon = now - self.window()
        for pid in list(self.revivable):
            ap = self.programs.get(pid)
            if ap is None or ap.state in FINAL or not ap.written_off:
                continue
            for attempt, host, when in ap.written_off:
                if when >= horizon and host != self.me and attempt not in ap.live:
                    ap.live[attempt] = host
                    self.changed(ap)
                    out.append(Note(what="isolated", program_id=ap.program_id, robot=host, attempt=attempt,
                                    detail="revived: this robot was cut off, not the host"))
            ap.written_off.clear()
        self.revivable.clear()
