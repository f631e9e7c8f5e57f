"""Whether a teammate that went quiet about a program still lives.

How this works: an origin whose host goes quiet about a program (no
acceptance, no heartbeat in time) asks whether the host itself still lives
(``ramps.core.failures``: a suspect keeps its copy, a host written off is
blacklisted). Two things say it does:

- anything at all from the host since the origin last heard about the
  program, at least a heartbeat period after: a heartbeat for another
  program, an acceptance, a probe reply (``Origin.heard``), a load report
  (``LoadView.report_age``);
- its load reports not yet overdue: a robot reports every period, or every
  few seconds in a large team (``RampsConfig.report_rate``), so a report
  older than the heartbeat timeout proves nothing where the next one is not
  due yet. ``LoadView.report_gap`` is the longest recent time between two
  of a robot's reports as they arrived: it takes a longer gap at once and
  gives back ``GAP_DECAY`` of the time that passes (reports on change come
  closer together); gaps longer than a view keeps a report (an outage, a
  stall) are not periods and are left out. It counts at most the longest
  period ``report_rate`` sets.

A cut or frozen host's last message is older than both. With a report every
period of a second or two this is the rule of a report younger than the
timeout less a heartbeat period.

Rules: no clock (``now`` comes in), no I/O.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from ramps.core.config import RampsConfig

#: the share of the time between two reports by which a robot's longest gap
#: shrinks when they come closer together
GAP_DECAY = 0.1


def still_heard(config: RampsConfig, window: float, heard_age: float | None, report_age: float | None,
                report_gap: float) -> bool:
    """Whether a host quiet about a program for ``window`` seconds (its timeout) was heard since:
    ``heard_age``, seconds since anything but a load report came from it; ``report_age``, since its
    latest report; ``report_gap``, the longest recent time between two of its reports."""
    since = window - config.heartbeat_period
    if heard_age is not None and heard_age < since:
        return True
    return report_age is not None and report_age < max(
        since, min(report_gap, config.longest_report_period) + config.heartbeat_period)
