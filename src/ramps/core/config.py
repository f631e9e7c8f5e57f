"""Tunable settings of the core: timeouts, back-off, placement tolerances.

Rules: plain data, validated when built; every duration is in seconds of the
driver's clock (virtual time in the simulator, monotonic time on a robot).
The defaults are for a team on WiFi running programs that take seconds to
minutes; the paper's own settings are available as ``RampsConfig.paper()``.
"""

from __future__ import annotations

from typing import Literal

import msgspec

#: the rules ``RampsConfig.place_by`` may name
PLACE_BY = ("own_end", "pool_end")


class RampsConfig(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    #: how long an origin waits for a host to accept an offload before it
    #: writes the host off (the paper's connection timeout)
    connect_timeout: float = 2.0
    #: how often a host tells an origin that its programs are still running
    heartbeat_period: float = 0.5
    #: silence after which an origin writes a host off (the paper's healthcheck)
    heartbeat_timeout: float = 2.0
    #: a failed program waits uniform(0, backoff_max) before it is re-placed
    backoff_max: float = 2.0
    #: programs of a host whose session is certainly gone (liveliness: a
    #: connection reset or an expired lease) wait only uniform(0, this)
    backoff_lost_max: float = 0.1
    #: a host resends an unacknowledged result this often
    result_resend: float = 1.0
    #: a host keeps an unacknowledged result this long (origin cut off)
    result_retention: float = 600.0
    #: a host keeps running the programs of an origin whose liveliness went
    #: (its node crashed, or its robot left the network), and keeps their
    #: results, this long for it to come back: an origin whose node restarts
    #: with its durable record (``ramps.core.durable``) finds them there;
    #: after this they are stopped and dropped (the record places them again)
    origin_hold: float = 30.0
    #: load reports older than this are ignored when placing (robot gone quiet)
    max_report_age: float = 10.0
    #: costs within this relative margin count as equal; ties are then broken
    #: towards the least utilised robot, then this one (ramps policy only). A
    #: wider margin keeps programs on their origin where a teammate is a little
    #: faster (docs/lab/2026-11-23-several-origins.md, "Ties")
    tie_tolerance: float = 0.005
    #: the margin instead, when larger, on a node that measures its own speed
    #: (no ``--speed``): identical robots that measure themselves differ by
    #: up to this, and a tie broken by that noise left an idle robot without
    #: programs while its teammates ran four each
    #: (docs/lab/2026-11-27-fastest-pieces.md)
    measured_tie_tolerance: float = 0.05
    #: in a view of more robots than this, ``ramps`` placement prices a
    #: short list of this many instead of all: the cheapest at its latest
    #: full scan (ties drawn at random), this robot and the burst plan's
    #: host; a full scan again each second, or once none of them is as cheap
    #: as the robot after them was (docs/lab/2026-11-27-sim-scale.md).
    #: 0: all, always
    placement_sample: int = 64
    #: in a team of more robots than ``placement_sample``, where more
    #: robots submit programs than this, a robot's load reports go to this
    #: many of them (``ramps.core.fanout``), not to all: traffic bounded
    #: per robot, at a cost to placement where the team is nearly full
    #: (docs/lab/2026-11-27-sim-scale-2.md). 0: to all
    report_fanout: int = 0
    #: periodic load reports a second a robot that places programs hears at
    #: most from its teammates: in a team of more teammates than this, each
    #: robot makes its periodic report go every ``teammates / report_rate``
    #: seconds instead of every report period (``report_period``), at most
    #: three quarters of ``relocate_stale`` and of ``max_report_age``, so
    #: that no view holds it stale; a change (its programs, its view of the
    #: team, its battery, speed or blacklist) still goes at the next period.
    #: An origin knows a report is not overdue until the longest recent gap
    #: between a robot's reports (``ramps.core.liveness``), so a host with
    #: late heartbeats is still suspected, not written off. 0: every period
    #: (docs/lab/2026-11-28-liveness.md)
    report_rate: float = 32.0
    #: a host busier than the origin expected still takes a program that
    #: computes there within its time budget plus this relative margin
    #: (ramps negotiation)
    admission_tolerance: float = 0.02
    #: how many times in a row a program may be turned away by busy hosts
    #: before the next host is asked to take it regardless (ramps negotiation)
    max_rejections: int = 8
    #: after a second rejection in a row a program waits uniform(0, this)
    #: seconds, doubling with each further one, before it is placed again
    contention_backoff: float = 0.05
    #: extra runnable tasks a host tolerates over the origin's estimate before
    #: it turns an offload away (ramps negotiation)
    admission_slack: float = 0.5
    #: with no report from any teammate for this long, an origin treats itself
    #: as cut off and runs displaced programs locally, still wanting the
    #: remote copies it wrote off just before: the first result is delivered
    isolation_timeout: float = 5.0
    #: robots' speeds are corrected (``ramps.core.speed``, policies that
    #: share load only): a node's own by its re-measurements while idle,
    #: a host's at its origins by comparing its results with the same
    #: program's runs on other robots, once the median of its last figures is
    #: off by more than ``speed_deadband`` and within ``speed_max_correction``
    #: times either way; false keeps every robot's boot measurement
    speed_learning: bool = True
    #: a robot's speed is corrected only when its figures are off by more than
    #: this fraction
    speed_deadband: float = 0.05
    #: a robot's speed is corrected by at most this factor either way; figures
    #: further off are taken as noise
    speed_max_correction: float = 2.0
    #: a program that lost this many hosts or workers ends with an error
    max_attempts: int = 50
    #: a host whose heartbeats (or acceptance) stop while it is still heard
    #: from (any message since, or a load report not yet overdue:
    #: ``ramps.core.liveness``) is suspected, not written off: its copy stays
    #: wanted and the program is also placed elsewhere at once; the first
    #: result wins
    hedge_suspects: bool = True
    #: a copy written off because its host fell silent or its session went
    #: (starved, frozen, cut for a while) is still the program's: its result,
    #: if it comes before the program ended, is delivered (the copy placed
    #: since is stopped), and a heartbeat from it makes it wanted again beside
    #: that copy (``ramps.core.isolation``). False (the paper): its result is
    #: discarded and its heartbeat answered with a cancel
    late_results: bool = True
    #: a host publishes a report of the instant whenever the programs it runs
    #: change, so origins deciding at once see each other's placements within
    #: a network latency instead of a report period (policies that share
    #: load only)
    prompt_reports: bool = True
    #: the shortest time between two such reports of the instant (0: one per
    #: change)
    prompt_report_interval: float = 0.0
    #: origins whose bursts come at one instant place them in the order of
    #: their names, each counting where those before it put theirs: a wait
    #: for the answers of those before it, only where teammates submit too
    #: (``ramps.core.claims``; policies that plan only)
    burst_claims: bool = True
    #: an origin's burst waits at most this long (s) per teammate before it
    #: for their answers, beyond twice the link's latency: a teammate on a
    #: throttled core answers late (a node of a fiftieth of a core stalled
    #: 2 s as a burst came), a lost one never; in a healthy team answers
    #: come in milliseconds and the wait ends with them
    burst_claim_wait: float = 1.0
    #: a node probes each teammate's link this often to measure T_comm
    #: (``ramps.core.links``); 0 = assume the configured network estimate
    probe_period: float = 5.0
    #: link probes a second a robot sends at most: one an application
    #: submits to probes at most this many teammates each ``probe_period``
    #: (the next ones in turn), one no application submits to re-measures a
    #: link every ``IDLE_REFRESH`` times as long as a submitter would, so
    #: probes per robot do not grow with the team (``links.probe_budget``).
    #: 0: no limit
    probe_rate: float = 8.0
    #: relocation after placement (the ramps policy): an origin re-evaluates
    #: the cost model for its running programs with what it now knows, and
    #: moves one when its remaining time where it runs exceeds the time to
    #: finish elsewhere (restart, or resume from its last checkpoint, plus the
    #: transfer of its parameters and checkpoint) by ``relocate_gain`` and
    #: ``relocate_min_gain``, for ``relocate_persist`` seconds in a row (a
    #: spike of load moves nothing). Off: programs stay where they started
    relocate: bool = True
    #: seconds between an origin's re-evaluations of its running programs
    relocate_period: float = 1.0
    #: a move must save at least this fraction of the time left where it runs
    relocate_gain: float = 0.2
    #: a move must save at least this many seconds
    relocate_min_gain: float = 5.0
    #: moves per program at most
    relocate_max_moves: int = 2
    #: no move within this many seconds of a program's acceptance by its host
    relocate_settle: float = 5.0
    #: a move must pay off for this many seconds in a row before it is made
    relocate_persist: float = 3.0
    #: calm relocation (docs/lab/2026-11-23-relocation.md, "Calm"): a
    #: program that does not checkpoint is never moved once the origin's
    #: upper estimate of its work done (its time there at one whole core of
    #: the host's speed, or its own progress if further) passes this fraction
    #: of its work; it is never moved back to a robot it already ran on
    relocate_max_done: float = 0.5
    #: no move off or onto a robot within this many seconds of a change of
    #: that robot's speed correction, nor any within it of this origin's own
    #: stall (its view and clock were behind): the estimate is uncertain
    relocate_calm: float = 5.0
    #: no move off or onto a robot whose latest load report is older than this
    relocate_stale: float = 4.0
    #: no move of a program whose learned work is scattered: its latest runs'
    #: largest per declared unit over their smallest above this
    relocate_max_spread: float = 1.5
    #: a robot whose battery is below this state of charge (0..1) takes no
    #: teammates' programs and hands back those it runs for them, which
    #: their origins place elsewhere at once (``ramps.core.battery``); its
    #: own programs still run, here or on teammates. No effect on a robot
    #: that reports no battery; 0: off
    battery_reserve: float = 0.2
    #: a robot below its reserve takes teammates' programs again once its
    #: charge is back at the reserve plus this, so one whose charge hovers
    #: at the reserve does not flip with every report
    battery_hysteresis: float = 0.05
    #: 0..1, set alike on every robot: how much placement (``ramps`` policy)
    #: weighs energy against time. 0 places for the earliest finish; 1 on the
    #: robot that spends least energy per unit of work (its watts per busy
    #: core over its speed, dearer the emptier its battery); between, a trade
    #: of one for the other (``ramps sim energy`` draws it)
    energy_weight: float = 0.0
    #: what ``ramps`` placement weighs of each host (eq. 1): "own_end", when
    #: the new program itself would end there (eq. 1 as published);
    #: "pool_end", when the last
    #: program of that host's pool (its cores, or its slots of the program's
    #: accelerator: every program there, the new one included) would end,
    #: then the program's own end; a host where the new program delays those
    #: already there then costs that delay. Programs with a deadline, and
    #: all when ``energy_weight`` is above 0, are placed by their own end
    #: either way (docs/lab/2026-11-27-pool-end.md)
    place_by: Literal["own_end", "pool_end"] = "pool_end"

    def __post_init__(self) -> None:
        if self.place_by not in PLACE_BY:
            raise ValueError(f"place_by must be one of {', '.join(PLACE_BY)}, got {self.place_by!r}")
        for name in self.__struct_fields__:
            value = getattr(self, name)
            if not isinstance(value, str) and value < 0:
                raise ValueError(f"{name} must be >= 0, got {value}")
        if self.heartbeat_timeout <= self.heartbeat_period:
            raise ValueError(
                f"heartbeat_timeout ({self.heartbeat_timeout}) must exceed "
                f"heartbeat_period ({self.heartbeat_period})"
            )
        if self.relocate and self.relocate_period <= 0:
            raise ValueError("relocate_period must be > 0 when relocate is on")
        if not self.relocate_max_done <= 1:
            raise ValueError(f"relocate_max_done must be 0..1, got {self.relocate_max_done}")
        if self.relocate_max_spread < 1:
            raise ValueError(f"relocate_max_spread must be >= 1, got {self.relocate_max_spread}")
        for name in ("battery_reserve", "battery_hysteresis", "energy_weight"):
            if not getattr(self, name) <= 1:
                raise ValueError(f"{name} must be 0..1, got {getattr(self, name)}")
        if self.speed_max_correction < 1:
            raise ValueError(f"speed_max_correction must be >= 1, got {self.speed_max_correction}")

    def report_period(self, period: float, teammates: int) -> float:
        """Seconds between a robot's periodic load reports on the wire, in a
        team of ``teammates`` besides it, where the publisher's period is
        ``period``: an origin then hears at most ``report_rate`` of them a
        second, or, in a team too large for that, one from each teammate
        every three quarters of the report age at which a view holds a
        report stale (``relocate_stale``, ``max_report_age``)."""
        if self.report_rate <= 0 or teammates <= self.report_rate * period:
            return period
        return max(period, min(teammates / self.report_rate, self.longest_report_period))

    @property
    def longest_report_period(self) -> float:
        """The longest time ``report_rate`` puts between a robot's periodic
        reports: three quarters of the age at which a view holds a report stale."""
        return 0.75 * min(self.relocate_stale, self.max_report_age)

    @classmethod
    def paper(cls) -> "RampsConfig":
        """Settings close to the paper's prototype (ROS actionlib timeouts,
        1 s pings, back-off of up to 10 s for minute-long programs)."""
        return cls(
            connect_timeout=5.0,
            heartbeat_period=1.0,
            heartbeat_timeout=5.0,
            backoff_max=10.0,
            backoff_lost_max=10.0,
            hedge_suspects=False,
            late_results=False,
            prompt_reports=False,
            probe_period=0.0,
            report_rate=0.0,
            relocate=False,
        )
