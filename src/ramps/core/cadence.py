"""When a robot's periodic load report goes on the wire (``ReportCadence``).

A robot's publisher makes a report every period; in a team of more
teammates than ``RampsConfig.report_rate`` one goes on the wire every
``RampsConfig.report_period`` instead (up to 3 s), so that an origin
of a large team hears a bounded number a second; one that says something a
teammate decides on differently (``moved``) goes at once. The runtime's
publisher (``ramps.runtime.node_reports``) and the simulator's
(``ramps.sim.engine``) both ask ``ReportCadence.due``. Pure: no clock, the
caller gives the time.
"""

from __future__ import annotations

import math

from msgspec.structs import astuple

from ramps.core.messages import LoadReport

#: seconds of rounding a publisher's clock may put between two of its periods (a tie goes now)
_SLACK = 1e-6


def moved(sent: LoadReport, report: LoadReport) -> bool:
    """Whether ``report`` says what a teammate decides on differently from
    ``sent``, the last that went: its programs (started, ended), its view of
    the team, cores, speed, battery, blacklist or accelerators, or whether it
    submits. Not its load besides programs: on a busy robot that moves every
    second, and it reaches the teammates within the period."""
    return (report.accepted_total != sent.accepted_total or report.finished_total != sent.finished_total
            or report.ramps_running != sent.ramps_running or report.sees != sent.sees
            or report.cores != sent.cores or report.speed != sent.speed or report.low_battery != sent.low_battery
            or report.blacklisted != sent.blacklisted or report.incarnation != sent.incarnation
            or report.submits != sent.submits or report.speed_class != sent.speed_class
            or [a[:4] for a in map(astuple, report.accelerators)] != [a[:4] for a in map(astuple, sent.accelerators)])


class ReportCadence:
    """The last periodic report that went on the wire (``sent``) and when."""

    __slots__ = ("sent", "sent_at")

    def __init__(self) -> None:
        self.sent: LoadReport | None = None
        self.sent_at = -math.inf

    def due(self, report: LoadReport, now: float, period: float, publish_period: float) -> bool:
        """Whether the periodic ``report``, made at ``now`` by a publisher of
        ``publish_period``, goes on the wire: once ``period``
        (``RampsConfig.report_period``) has passed since the last that went, to
        the nearest publish (the earlier of two as near), or now where it
        ``moved``. Records it if so."""
        sent = self.sent
        if sent is None or now - self.sent_at >= period - publish_period / 2 - _SLACK or moved(sent, report):
            self.sent, self.sent_at = report, now
            return True
        return False
