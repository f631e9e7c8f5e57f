"""When each teammate was last heard from, and how far apart its load reports come.

How this works: an origin whose host goes quiet about a program (no
acceptance, no heartbeat in time) asks whether the host itself still lives
(``ramps.core.failures``: a suspect keeps its copy, a host written off is
blacklisted). Two things say it does:

- anything at all from the host since the origin last heard about the
  program: a heartbeat for another program, an acceptance, a probe reply,
  a load report (``heard``);
- its load reports not yet overdue: a robot reports every period, or every
  few seconds in a large team (``RampsConfig.report_rate``), so a report
  older than the heartbeat timeout proves nothing where the next one is not
  due yet. ``report_gap`` is the longest recent time between two of a
  robot's reports as they arrived: it takes a longer gap at once and gives
  back a tenth of the time that passes (reports on change come closer
  together), and gaps longer than a view keeps a report (an outage, a
  stall) are not periods at all and are left out.

Rules: no clock (``now`` comes in), no I/O; a handful of floats per teammate.
"""

from __future__ import annotations

#: the share of the time between two reports by which a robot's longest gap
#: shrinks when they come closer together
GAP_DECAY = 0.1


class Liveness:
    """Per teammate: when anything last came from it, its last report's
    arrival, and the longest recent gap between its reports."""

    __slots__ = ("_heard", "_reports", "longest")

    def __init__(self, longest: float) -> None:
        if not longest > 0:
            raise ValueError(f"the longest report gap must be > 0, got {longest}")
        #: gaps longer than this are outages, not a robot's report period
        self.longest = longest
        self._heard: dict[str, float] = {}
        #: robot -> [the last report's arrival, the longest recent gap]
        self._reports: dict[str, list[float]] = {}

    def heard(self, robot: str, now: float, report: bool) -> None:
        """A message from ``robot`` arrived; ``report``: a load report."""
        self._heard[robot] = now
        if not report:
            return
        r = self._reports.get(robot)
        if r is None:
            self._reports[robot] = [now, 0.0]
            return
        gap = now - r[0]
        r[0] = now
        if gap <= self.longest:
            r[1] = max(gap, r[1] - GAP_DECAY * gap)

    def heard_age(self, robot: str, now: float) -> float | None:
        """Seconds since anything came from ``robot`` (None: never)."""
        at = self._heard.get(robot)
        return None if at is None else now - at

    def report_gap(self, robot: str) -> float:
        """The longest recent time between two of ``robot``'s reports (0 before two arrived)."""
        r = self._reports.get(robot)
        return 0.0 if r is None else r[1]
