"""The load server: one robot's view of its team's load.

How this works: the view keeps the latest ``LoadReport`` of every robot with
the time it arrived, a blacklist of robots written off, and the *bookings*
this robot's own programs made on hosts that the hosts' reports may not show
yet. Two readings of the same data serve the two families of policy:

* the paper's: a booking raises the stored load until the target's next
  report arrives and overwrites it, even if that report was measured before
  the program started (stale information, as in the ROS prototype);
* ramps': a booking counts until a report *proves* it is included, using the
  host's monotonic ``accepted_total``/``finished_total`` counters; so nothing
  is counted twice and nothing is forgotten early.

A blacklisted robot is lifted only when it publishes again (a report with a
higher sequence number, or from a new incarnation). Pure state: no clock, no
I/O; ``now`` is passed in.
"""

from __future__ import annotations

import heapq
import itertools

from ramps.core.accelerators import reported_left, work_left
from ramps.core.cost import program_share
from ramps.core.liveness import GAP_DECAY
from ramps.core.loadview_scan import Scanning
from ramps.core.messages import MAX_LISTED, AcceleratorSeen, LoadReport
from ramps.core.reportcheck import report_problem

__all__ = ["LoadView", "report_problem"]

class _Booking:
    __slots__ = ("accept_seq", "finish_seq")

    def __init__(self) -> None:
        self.accept_seq: int | None = None
        self.finish_seq: int | None = None


#: what a booking is to the counts, given a report's totals (``_kind``)
_KEPT, _UNSEEN_ACCEPT, _UNSEEN_FINISH, _GONE = 0, 1, 2, 3


def _kind(b: _Booking, acc_total: int, fin_total: int) -> int:
    """How a report with these totals sees booking ``b``: not started in it (and not finished: it
    counts as running), started and finished but the finish not in it (it counts as ended), started
    and finished in it (the booking is done with), or anything else (the report says it all)."""
    if b.accept_seq is None or b.accept_seq > acc_total:
        # not in the report yet; if it already finished it runs no more
        # (kept, because a report made before the finish may come late)
        return _UNSEEN_ACCEPT if b.finish_seq is None else _KEPT
    if b.finish_seq is None:
        return _KEPT
    return _UNSEEN_FINISH if b.finish_seq > fin_total else _GONE


class _Robot:
    __slots__ = ("report", "received_at", "bookings", "unseen_accept", "unseen_finish", "paper_booked", "lost",
                 "counted", "waiting_accept", "waiting_finish", "stale", "accel", "row", "row_factor", "row_rate", "gap")

    def __init__(self) -> None:
        self.report: LoadReport | None = None
        self.received_at = 0.0
        #: the longest recent time between two of its reports (``ramps.core.liveness``)
        self.gap = 0.0
        self.bookings: dict[tuple[str, int], _Booking] = {}
        #: bookings a report does not include yet / finished ones it still shows
        self.unseen_accept = 0
        self.unseen_finish = 0
        #: the paper's counter: bookings since the last report overwrote them
        self.paper_booked = 0
        #: liveliness says the robot is gone
        self.lost = False
        #: the (accepted_total, finished_total) the counts above are of
        self.counted = (-1, -1)
        #: bookings whose acceptance / finish a report has yet to show, by
        #: sequence number: (seq, tie, key, booking), pushed when the number
        #: is set, possibly outdated (the booking went or changed since:
        #: skipped when taken out)
        self.waiting_accept: list[tuple[int, int, tuple[str, int], _Booking]] = []
        self.waiting_finish: list[tuple[int, int, tuple[str, int], _Booking]] = []
        #: a booking was made again under a key it had: counted afresh at the next change
        self.stale = False
        #: bookings of programs on an accelerator (kind, booking, work there, placed at):
        #: not CPU programs, so kept apart from ``bookings`` (``accelerator_rows``)
        self.accel: dict[tuple[str, int], tuple[str, _Booking, float, float]] = {}
        #: its ``scan`` row kept until the report or the counts change (None: to make), the
        #: speed factor it was made with, and relocation's rate of it (``ramps.core.loadview_scan``)
        self.row: tuple[str, float, float, float, float, float] | None = None
        self.row_factor = 1.0
        self.row_rate: float | None = None


class LoadView(Scanning):
    def __init__(self, me: str, *, cores: int, speed: float, max_report_age: float = 10.0,
                 program_weight: float = 1.0) -> None:
        self.me = me
        self.cores = cores
        self.speed = speed
        self.program_weight = program_weight
        self.max_report_age = max_report_age
        self._robots: dict[str, _Robot] = {me: _Robot()}
        self._blacklist: dict[str, tuple[int, int]] = {}
        self.last_remote_report: float | None = None
        self.reports_received = 0
        self.bad_reports = 0
        #: robot -> how much faster than it reports it runs programs (set by
        #: ``Node`` from ``HostSpeeds``; absent = 1)
        self.speed_factor: dict[str, float] = {}
        #: tie-breaks of the bookings waiting for a report (``_Robot.waiting_accept``)
        self._ties = itertools.count()
        #: teammates whose latest report says they are below their battery
        #: reserve (``ramps.core.battery``): origins leave them out of placement
        self.low_battery: set[str] = set()
        #: this robot's accelerators until its own first report is in
        self.accelerators: list[AcceleratorSeen] = []

    # ------------------------------------------------------------ reports
    def on_report(self, report: LoadReport, now: float, *, fresh: bool = False) -> bool:
        """Take a report in. Returns True if it lifted a blacklisting.

        ``fresh`` marks a report made on the spot (sent with a rejection): it replaces a periodic
        report with the same sequence number. A report that ``report_problem`` refuses is counted in
        ``bad_reports`` and dropped."""
        if report_problem(report) is not None:
            self.bad_reports += 1
            return False
        return self.on_checked_report(report, now, fresh=fresh)

    def on_checked_report(self, report: LoadReport, now: float, *, fresh: bool = False) -> bool:
        """``on_report`` for a report its caller has just found sound (``report_problem`` returned
        None): the same, without checking it again."""
        rob = self._robots.get(report.robot)
        if rob is None:
            rob = self._robots[report.robot] = _Robot()
        old = rob.report
        if old is not None and old.incarnation == report.incarnation and (
            report.seq < old.seq or (report.seq == old.seq and not fresh)
        ):
            return False  # duplicate or reordered: keep the newer one
        if old is not None and old.incarnation != report.incarnation:
            # the robot restarted: whatever we booked there died with it
            rob.bookings.clear()
            rob.accel.clear()
            rob.stale = True
        elif old is not None and (gap := now - rob.received_at) <= self.max_report_age:
            shrunk = rob.gap - GAP_DECAY * gap  # an outage is no period (``ramps.core.liveness``)
            rob.gap = gap if gap > shrunk else shrunk
        rob.report, rob.received_at, rob.row = report, now, None
        if report.low_battery and report.robot != self.me:
            self.low_battery.add(report.robot)
        elif self.low_battery:
            self.low_battery.discard(report.robot)
        rob.paper_booked = 0
        rob.lost = False
        self.reports_received += 1
        if report.robot != self.me:
            self.last_remote_report = now
        wa, wf, (was_acc, was_fin) = rob.waiting_accept, rob.waiting_finish, rob.counted
        acc_total, fin_total = report.accepted_total, report.finished_total
        if (not rob.stale and was_acc <= acc_total and was_fin <= fin_total and (not wa or wa[0][0] > acc_total)
                and (not wf or wf[0][0] > fin_total)):
            rob.counted = (acc_total, fin_total)  # ``_count_report``'s common case, without a call
        else:
            self._count_report(rob)
        bl = self._blacklist.get(report.robot)
        if bl is not None and (report.incarnation != bl[0] or report.seq > bl[1]):
            del self._blacklist[report.robot]
            return True
        return False

    # Counting bookings. ``unseen_accept``/``unseen_finish`` are always what ``_recount`` (every
    # booking through ``_kind``) would make them, and a booking the current report shows started and
    # finished is dropped. They change only where a booking changes (``accepted``, ``released``) or
    # where a report's totals pass a booking's sequence numbers, so only those bookings are looked
    # at: a report or a result costs O(log n) per booking it settles, not O(n) per booking there.
    def _recount(self, rob: _Robot) -> None:
        """Count every booking afresh (and index those a report has yet to show)."""
        rep = rob.report
        acc_total = rep.accepted_total if rep else -1
        fin_total = rep.finished_total if rep else -1
        counts = [0, 0, 0, 0]
        waiting_accept: list[tuple[int, int, tuple[str, int], _Booking]] = []
        waiting_finish: list[tuple[int, int, tuple[str, int], _Booking]] = []
        for key, b in list(rob.bookings.items()):
            kind = _kind(b, acc_total, fin_total)
            counts[kind] += 1
            if kind == _GONE:
                del rob.bookings[key]  # report shows it started and ended
                continue
            if b.accept_seq is not None and b.accept_seq > acc_total:
                waiting_accept.append((b.accept_seq, next(self._ties), key, b))
            if b.finish_seq is not None and b.finish_seq > fin_total:
                waiting_finish.append((b.finish_seq, next(self._ties), key, b))
        heapq.heapify(waiting_accept)
        heapq.heapify(waiting_finish)
        rob.waiting_accept, rob.waiting_finish = waiting_accept, waiting_finish
        rob.unseen_accept = counts[_UNSEEN_ACCEPT]
        rob.unseen_finish = counts[_UNSEEN_FINISH]
        rob.counted = (acc_total, fin_total)
        rob.stale = False
        rob.row = None

    def _count_report(self, rob: _Robot) -> None:
        """``rob`` has a new report: the bookings whose sequence numbers its totals passed change how
        they count (a report whose totals went back, which no honest host sends, is counted afresh)."""
        rep = rob.report
        assert rep is not None
        acc_total, fin_total = rep.accepted_total, rep.finished_total
        was_acc, was_fin = rob.counted
        if rob.stale or acc_total < was_acc or fin_total < was_fin:
            self._recount(rob)
            return
        wa, wf = rob.waiting_accept, rob.waiting_finish
        if (not wa or wa[0][0] > acc_total) and (not wf or wf[0][0] > fin_total):
            rob.counted = (acc_total, fin_total)  # no booking's number passed (most reports an origin hears)
            return
        passed: dict[int, tuple[tuple[str, int], _Booking]] = {}
        for heap, total, field in ((rob.waiting_accept, acc_total, "accept_seq"),
                                   (rob.waiting_finish, fin_total, "finish_seq")):
            while heap and heap[0][0] <= total:
                seq, _, key, b = heapq.heappop(heap)
                if getattr(b, field) == seq and rob.bookings.get(key) is b:
                    passed[id(b)] = (key, b)
        rob.counted = (acc_total, fin_total)
        for key, b in passed.values():
            before = _kind(b, was_acc, was_fin)
            after = _kind(b, acc_total, fin_total)
            self._move(rob, key, before, after)

    def _move(self, rob: _Robot, key: tuple[str, int], before: int, after: int) -> None:
        """The booking ``key`` counted as ``before`` and counts as ``after``
        now; one the report shows ended is dropped."""
        rob.row = None
        if before == _UNSEEN_ACCEPT:
            rob.unseen_accept -= 1
        elif before == _UNSEEN_FINISH:
            rob.unseen_finish -= 1
        if after == _UNSEEN_ACCEPT:
            rob.unseen_accept += 1
        elif after == _UNSEEN_FINISH:
            rob.unseen_finish += 1
        elif after == _GONE:
            del rob.bookings[key]

    def report_of(self, robot: str) -> LoadReport | None:
        rob = self._robots.get(robot)
        return rob.report if rob else None

    def report_age(self, robot: str, now: float) -> float | None:
        rob = self._robots.get(robot)
        return None if rob is None or rob.report is None else now - rob.received_at

    def report_gap(self, robot: str) -> float:
        """The longest recent time between two of ``robot``'s reports (0 before two arrived)."""
        rob = self._robots.get(robot)
        return 0.0 if rob is None else rob.gap

    def robots(self) -> list[str]:
        return list(self._robots)

    def holds(self, robot: str) -> bool:
        """Whether ``robot`` is one of ``robots``."""
        return robot in self._robots

    def stale(self, now: float, seconds: float) -> list[str]:
        """The teammates whose latest report is older than ``seconds`` (``report_age``), or that
        sent none."""
        me = self.me
        return [name for name, rob in self._robots.items()
                if name != me and (rob.report is None or now - rob.received_at > seconds)]

    def size(self) -> int:
        """How many robots the view holds (``robots``' length, without the list)."""
        return len(self._robots)

    # ------------------------------------------------------------ bookings
    def book(self, robot: str, program_id: str, attempt: int, accelerator: str = "", work: float = 0.0,
             now: float = 0.0) -> None:
        """Count a program placed on ``robot`` until its reports show it (on that kind of ``accelerator`` there,
        with its ``work`` there, placed at ``now``; "" = on a CPU)."""
        rob = self._robots.get(robot)
        if rob is None:
            rob = self._robots[robot] = _Robot()
        key = (program_id, attempt)
        if accelerator:
            rob.accel[key] = (accelerator, _Booking(), work, now)
            return
        if key in rob.bookings:
            rob.stale = True  # the one it replaces still counts, until the next change counts afresh
        rob.bookings[key] = _Booking()
        rob.unseen_accept += 1
        rob.row = None
        rob.paper_booked += 1

    def accepted(self, robot: str, program_id: str, attempt: int, accept_seq: int) -> None:
        rob = self._robots.get(robot)
        key = (program_id, attempt)
        if rob is not None and key in rob.accel:
            ab = rob.accel[key][1]
            if ab.accept_seq is None:
                ab.accept_seq = accept_seq
            return
        b = rob.bookings.get(key) if rob else None
        if rob is None or b is None or b.accept_seq is not None:
            return
        if rob.stale:
            b.accept_seq = accept_seq
            self._recount(rob)
            return
        before = _kind(b, *rob.counted)
        b.accept_seq = accept_seq
        if accept_seq > rob.counted[0]:
            heapq.heappush(rob.waiting_accept, (accept_seq, next(self._ties), key, b))
        self._move(rob, key, before, _kind(b, *rob.counted))

    def released(self, robot: str, program_id: str, attempt: int, finish_seq: int | None) -> None:
        """The program ended (``finish_seq`` known) or left the host (None)."""
        rob = self._robots.get(robot)
        key = (program_id, attempt)
        if rob is not None and key in rob.accel:
            ab = rob.accel[key][1]
            if finish_seq is None or ab.accept_seq is None:
                del rob.accel[key]
            else:
                ab.finish_seq = finish_seq
            return
        b = rob.bookings.get(key) if rob else None
        if rob is None or b is None:
            return
        before = _kind(b, *rob.counted)
        if finish_seq is None or b.accept_seq is None:
            del rob.bookings[key]
            if rob.stale:
                self._recount(rob)
            else:
                self._move(rob, key, before, _KEPT)
            return
        b.finish_seq = finish_seq
        if rob.stale:
            self._recount(rob)
            return
        if finish_seq > rob.counted[1]:
            heapq.heappush(rob.waiting_finish, (finish_seq, next(self._ties), key, b))
        self._move(rob, key, before, _kind(b, *rob.counted))

    # ------------------------------------------------------------ estimates
    def ramps_programs(self, robot: str) -> float:
        """Ramps programs on ``robot`` now, by ramps' reading of the view."""
        rob = self._robots[robot]
        base = rob.report.ramps_running if rob.report else 0
        return max(0, base + rob.unseen_accept - rob.unseen_finish)

    def background(self, robot: str) -> float:
        """Competing tasks on ``robot`` that are not ramps programs."""
        rep = self._robots[robot].report
        return 0.0 if rep is None else max(0.0, rep.runnable - rep.ramps_avg)

    def remaining_work(self, robot: str, now: float, programs: int, unknown: float) -> list[float] | None:
        """Work units left in each of the ``programs`` ramps programs this view counts on ``robot``:
        the host's last estimate (``LoadReport.remaining``) aged by processor sharing since it
        arrived; programs the report does not list yet count ``unknown`` units each, and when the
        view counts fewer programs than the report lists, the smallest ended. None when the view
        counts more than a report can list (``MAX_LISTED``)."""
        if programs > MAX_LISTED:
            return None  # more than a report lists: the count-based estimate stands
        rob = self._robots.get(robot)
        rep = rob.report if rob else None
        if rob is None or rep is None or not rep.remaining:
            return [unknown] * programs
        listed = rep.remaining
        age = max(0.0, now - rob.received_at)
        background = max(0.0, rep.runnable - rep.ramps_avg)
        speed = self.speed_of(robot, rep.speed)
        step = age * speed * program_share(rep.cores, len(listed), background, rep.program_weight)
        left = [x - step for x in listed]
        left.sort()
        if len(left) > programs:
            del left[:len(left) - programs]
        # x if x > 0.0 else 0.0 is max(0.0, x), NaN and -0.0 included, without a call per item
        return [x if x > 0.0 else 0.0 for x in left] + [unknown] * (programs - len(left))

    def accelerator_rows(self, now: float, kind: str, exclude: frozenset[str] = frozenset()
                         ) -> list[tuple[str, int, float, float, list[float]]]:
        """(robot, slots, speed, programs, known) for every candidate (``scan``'s) with accelerators of
        ``kind``: the programs on them by its last report, plus those booked there it does not show started,
        less those it does not show ended; the work left in what the report lists (``reported_left``) and in
        what this view placed there that it does not show, or all of those where it lists none (``work_left``)."""
        horizon = now - self.max_report_age
        out = []
        for name, rob in self._robots.items():
            rep = rob.report
            if name in exclude or name != self.me and (rep is None or rob.lost or rob.received_at < horizon
                                                       or name in self._blacklist):
                continue
            seen = next((a for a in (rep.accelerators if rep is not None else self.accelerators) if a.kind == kind), None)
            if seen is None:
                continue
            programs = seen.running if rep is not None else 0
            listed = rep is not None and (bool(seen.remaining) or not seen.running)  # [] from older nodes
            placed: list[tuple[float, float]] = []
            ended: list[tuple[float, float]] = []
            for key, (k, b, work, at) in list(rob.accel.items()):
                state = _kind(b, *rob.counted)
                if state == _GONE:
                    del rob.accel[key]
                elif k == kind:
                    programs += (state == _UNSEEN_ACCEPT) - (state == _UNSEEN_FINISH)
                    if b.finish_seq is None and (state == _UNSEEN_ACCEPT or not listed):
                        placed.append((work, at))
                    elif state == _UNSEEN_FINISH:
                        ended.append((work, at))
            programs = max(0, programs)
            known = work_left(placed, now, seen.count, seen.speed, programs)
            if listed and programs:
                known = sorted(known + reported_left(seen.remaining, now, rob.received_at, seen.count,
                                                     seen.speed, seen.running, ended))[-programs:]
            out.append((name, seen.count, seen.speed, float(programs), known))
        return out

    def accelerator_kinds(self, robot: str) -> frozenset[str]:
        """The kinds of accelerator ``robot`` advertised last."""
        rob = self._robots.get(robot)
        if rob is None or rob.report is None:
            return frozenset(a.kind for a in self.accelerators) if robot == self.me else frozenset()
        return frozenset(a.kind for a in rob.report.accelerators)

    def short_of_memory(self, memory: int) -> frozenset[str]:
        """Robots whose last report shows less than ``memory`` bytes free once
        the programs booked there since count ``memory`` each (robots that
        report no figure are not judged)."""
        if memory <= 0:
            return frozenset()
        return frozenset(name for name, rob in self._robots.items()
                         if rob.report is not None and rob.report.mem_free > 0
                         and rob.report.mem_free - rob.unseen_accept * memory < memory)

    def paper_load(self, robot: str) -> float:
        """Busy cores as the paper's load server sees them: the last report's
        CPU load (which saturates at 100%) plus bookings made since it came."""
        rob = self._robots[robot]
        cpu = rob.report.cpu_busy if rob.report else 0.0
        return cpu + rob.paper_booked

    def capacity(self, robot: str) -> tuple[int, float]:
        rep = self._robots[robot].report if robot in self._robots else None
        if rep is None:
            return (self.cores, self.speed) if robot == self.me else (1, 1.0)
        return rep.cores, self.speed_of(robot, rep.speed)

    def speed_of(self, robot: str, reported: float) -> float:
        """A robot's speed as placement uses it: what it reports, times the
        factor its results showed (``ramps.core.speed.HostSpeeds``)."""
        return reported * self.speed_factor.get(robot, 1.0)

    # ------------------------------------------------------------ blacklist / liveness
    def blacklist(self, robot: str) -> bool:
        """Write a robot off until it publishes again. False if it already was."""
        if robot == self.me or robot in self._blacklist:
            return False
        rep = self.report_of(robot)
        self._blacklist[robot] = (rep.incarnation, rep.seq) if rep else (-1, -1)
        return True

    def is_blacklisted(self, robot: str) -> bool:
        return robot in self._blacklist

    def blacklisted(self) -> list[str]:
        return sorted(self._blacklist)

    def is_lost(self, robot: str) -> bool:
        rob = self._robots.get(robot)
        return rob is not None and rob.lost

    def set_lost(self, robot: str, lost: bool) -> None:
        rob = self._robots.get(robot)
        if rob is not None:
            rob.lost = lost

    def isolated(self, now: float, timeout: float) -> bool:
        """True when this robot has heard from teammates before but from none
        for ``timeout`` seconds, or liveliness says all of them are gone."""
        if self.last_remote_report is None:
            return False
        others = [r for n, r in self._robots.items() if n != self.me and r.report is not None]
        if others and all(r.lost for r in others):
            return True
        return now - self.last_remote_report > timeout
