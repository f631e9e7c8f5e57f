"""The load server's scan: every candidate robot's figures in one pass
(``ramps.core.loadview.LoadView`` is a ``Scanning``).

How this works: a row is (robot, cores, speed, ramps, background, weight),
read from the robot's latest report, the bookings that report does not
show yet, and its speed correction. Each robot's row is kept between scans
(``_Robot.row``) until one of those changes: ``LoadView`` drops it with
every report taken in and every change of the booking counts, and a scan
makes it again when the speed factor it was made with is no longer the
robot's. Placement scans a fleet's view for every program and relocation
once a second: most rows come out as they went in. Which robots are
candidates (a fresh report, not lost, not blacklisted) is decided at each
scan. Rules: pure state, ``now`` passed in.
"""

from __future__ import annotations

from typing import Any

from ramps.core.cost import program_cores, program_share

#: (robot, cores, speed, ramps, background, weight)
Row = tuple[str, float, float, float, float, float]


class Scanning:
    """``scan`` and what reads it, over a ``LoadView``'s robots."""

    me: str
    cores: int
    speed: float
    program_weight: float
    max_report_age: float
    speed_factor: dict[str, float]
    _robots: dict[str, Any]
    _blacklist: dict[str, tuple[int, int]]

    def _passed_over(self, name: str, rob: Any, horizon: float) -> bool:
        """A teammate placed on by no one now: no report since ``horizon``, lost or blacklisted."""
        return name != self.me and (rob.report is None or rob.lost or rob.received_at < horizon or name in self._blacklist)

    def candidates(self, now: float) -> list[str]:
        """``scan``'s robots without their figures: this robot and every teammate not ``_passed_over``."""
        horizon, me, blacklist = now - self.max_report_age, self.me, self._blacklist
        return [n for n, r in self._robots.items()
                if n == me or not (r.report is None or r.lost or r.received_at < horizon or n in blacklist)]

    def _row(self, name: str, rob: Any, paper: bool) -> Row:
        """``rob``'s row as of now (its speed factor read now)."""
        rep = rob.report
        background = 0.0
        if paper:
            ramps = (rep.cpu_busy if rep else 0.0) + rob.paper_booked
        else:
            base = rep.ramps_running if rep else 0
            ramps = max(0, base + rob.unseen_accept - rob.unseen_finish)
            if rep is not None and rep.runnable > rep.ramps_avg:
                background = rep.runnable - rep.ramps_avg
        cores: float
        if rep is None:  # only this robot gets here without a report
            cores, speed, weight = self.cores, self.speed * self.speed_factor.get(name, 1.0), self.program_weight
        else:
            cores, speed, weight = rep.cores, rep.speed * self.speed_factor.get(name, 1.0), rep.program_weight
            if rep.node_cpu and not paper:
                cores = program_cores(rep.cores, rep.node_cpu)
        return (name, cores, speed, ramps, background, weight)

    def _rows(self, now: float, paper: bool, only: list[str] | None) -> list[Row]:
        """Every candidate's row, kept ones where they still hold (ramps' reading of a robot with a report)."""
        horizon, factors, robots, me, blacklist = (now - self.max_report_age, self.speed_factor, self._robots,
                                                   self.me, self._blacklist)
        out = []
        for name, rob in robots.items() if only is None else zip(only, map(robots.get, only)):
            if rob is None:  # a name of ``only`` not in the view
                continue
            rep = rob.report
            if name != me and (rep is None or rob.lost or rob.received_at < horizon or name in blacklist):
                continue
            if paper or rep is None:
                out.append(self._row(name, rob, paper))
                continue
            row = rob.row
            factor = factors.get(name, 1.0)
            if row is None or rob.row_factor != factor:
                row = rob.row = self._row(name, rob, False)
                rob.row_factor, rob.row_rate = factor, None
            out.append(row)
        return out

    def scan(self, now: float, exclude: frozenset[str], paper: bool = False,
             only: list[str] | None = None) -> list[Row]:
        """(robot, cores, speed, ramps, background, weight) for every candidate,
        in one pass: ramps programs there by ramps' reading of the view, other
        runnable tasks, and the scheduler weight of a program against them
        (with ``paper``, ``ramps`` is the paper's load and background 0).
        ``cores`` are those the robot's programs can have: its cores less
        what its node itself uses (``LoadReport.node_cpu``, at most half of
        them; the paper's prototype counted all of them). The hot path of
        placement in large teams: ``ramps_programs`` + ``background`` (or
        ``paper_load``) of each of ``candidates``, without objects between.
        An ``exclude`` that would leave no candidate at all is ignored.
        ``only``: these robots alone, in this order (a sample of a large
        team, ``RampsConfig.placement_sample``; names not in the view skipped)."""
        out = self._rows(now, paper, only)
        if exclude:
            kept = [e for e in out if e[0] not in exclude]
            if kept:
                return kept
        return out

    def rows_and_best_rate(self, now: float) -> tuple[dict[str, Row], float]:
        """``scan``'s rows by robot (nothing excluded), and the fastest a new
        program could run on any of them by the count of tasks: the most of
        ``speed * program_share(cores, ramps + 1, background, weight)``, 0.0
        with no robot (relocation's first estimate, ``ramps.core.relocation``)."""
        rows = {}
        best = 0.0
        horizon, factors, me, blacklist = now - self.max_report_age, self.speed_factor, self.me, self._blacklist
        for name, rob in self._robots.items():  # ``_rows``' pass, with the rates
            rep = rob.report
            if name != me and (rep is None or rob.lost or rob.received_at < horizon or name in blacklist):
                continue
            rate = None
            if rep is None:
                row = self._row(name, rob, False)
            else:
                row = rob.row
                factor = factors.get(name, 1.0)
                if row is None or rob.row_factor != factor:
                    row = rob.row = self._row(name, rob, False)
                    rob.row_factor, rob.row_rate = factor, None
                rate = rob.row_rate
            if rate is None:
                _, cores, speed, ramps, background, weight = row
                rate = speed * program_share(cores, ramps + 1.0, background, weight)
                if rep is not None:
                    rob.row_rate = rate
            rows[name] = row
            if rate > best:
                best = rate
        return rows, best
