"""Bursts of several origins at one instant: each origin sees the bursts
of those before it in the order of names before it places its own.

How this works: origins that get a burst at the same instant would each
plan it blind to the others' (``ramps.core.burst``: the reports of that
instant come a latency later), and two would plan on the same slot or the
same free cores. So at the end of its batch (``Node.flush``) an origin with
a burst that its policy plans (``Policy.plans``, ``RampsConfig.burst_claims``):

- places it at once when it is one program (its host admits it against its
  next best robot, its time budget, which a plan's end does not), or when
  no teammate before it in the order of names could claim (a candidate
  that says an application submits there: ``LoadReport.submits``, or a
  claim of its own);
- else tells every teammate that could claim that it has a burst
  (``BurstClaim``, ``planned`` False) and holds it until each teammate
  before it has answered: with where its own burst went (``planned``
  True), or, holding none, with an empty claim at once. It waits at most
  twice the link's latency plus ``RampsConfig.burst_claim_wait`` per
  teammate before it: a teammate on a throttled core answers tens of
  milliseconds late, and one that never answers (a node of an earlier
  release) holds it no longer than that.

Once placed, an origin sends every teammate that could claim where its
burst of two programs or more went: the work it put on each pool (robot,
accelerator kind). A plan counts a claim as work on its pools (``claimed``,
``Pool.known``) until the view shows it, for at most ``KEEP`` seconds: on
this robot, as the claimer's programs start here; on the claimer, once its
reports reach the claim's ``accepted`` count; elsewhere, once the robot's
reports have accepted as many programs since the claim came as the claims
put there. So a claim that comes before the burst it matters to, or a
throttled host that reports before it has handled its offers, still counts.
An origin none of whose teammates submit never waits.

Rules: no clock (``now`` comes in), no I/O.
"""

from __future__ import annotations

from typing import Protocol

from ramps.core.burst import BurstOrigin, place_held
from ramps.core.events import Action, Send
from ramps.core.executor import Executor
from ramps.core.messages import BurstClaim, ClaimedPool
from ramps.core.program import FINAL


#: how long (s) a claim counts at most, unless the view shows its work sooner (a
#: claim on a robot that refused its program shows there never): a throttled
#: origin's view of a robot can be seconds old, and a claim dropped at 2 s let
#: one put a third program on a robot of two (docs/lab/2026-11-28-claims-throttled.md)
KEEP = 10.0


class ClaimingOrigin(BurstOrigin, Protocol):
    """What claims read and change of ``ramps.core.origin.Origin``."""

    me: str
    claimed: dict[tuple[str, str], list[float]]


class Claims:
    """The claims this robot heard, and the wait of its own burst
    (``executor``: this robot's, whose programs a claim on it may be)."""

    def __init__(self, executor: Executor) -> None:
        self.executor = executor
        #: robot -> (when its latest claim of a burst came, the claim, each
        #: pool robot's accepted count in this robot's view then)
        self.heard: dict[str, tuple[float, BurstClaim, dict[str, int]]] = {}
        #: robot -> when its latest claim of a burst, or empty answer, came (``planned`` True)
        self.answered: dict[str, float] = {}
        #: robot -> when it last said that it plans a burst (``planned`` False)
        self.bursting: dict[str, float] = {}
        #: when this robot's held burst began to wait (None: it does not)
        self.since: float | None = None
        #: the teammates before this robot that could claim, when it began
        self.earlier: tuple[str, ...] = ()
        #: twice the latency to the farthest of them: an answer takes this long at least
        self.wait = 0.0
        #: when the held burst goes whether or not all have answered
        self.limit = 0.0
        #: when to look again while waiting (``Node.next_deadline``)
        self.check: float | None = None
        #: teammates that say an application submits there
        self.submitters: set[str] = set()

    def on_claim(self, origin: ClaimingOrigin, sender: str, msg: BurstClaim, now: float, out: list[Action]) -> None:
        """A teammate's claim came: kept; answered at once if it asks this robot
        (before it by name) and this robot plans no burst; and the burst held
        for it placed if it was the last awaited."""
        self.submitters.add(sender)
        if not msg.planned:
            self.bursting[sender] = now
            if sender > origin.me and self.since is None and not self._will_claim(origin):
                out.append(Send(to=sender, msg=BurstClaim(planned=True, accepted=self.executor.accepted_total)))
        else:
            self.answered[sender] = now
            if msg.pools:
                reports = [origin.view.report_of(pool.robot) for pool in msg.pools]
                self.heard[sender] = (now, msg, {pool.robot: -1 if report is None else report.accepted_total
                                                 for pool, report in zip(msg.pools, reports)})
        if self.since is not None:
            self.flush(origin, now, out)

    def due(self, held_since: float) -> float:
        """When the held burst is due a look: at once unless it waits."""
        return held_since if self.since is None or self.check is None else self.check

    def flush(self, origin: ClaimingOrigin, now: float, out: list[Action]) -> None:
        """The batch is over (or a claim came, or the wait's time): place
        the held burst if nothing before it is still to come."""
        if not origin.held:
            self.since = self.check = None
            return
        if self.since is None and not self._start(origin, now, out):
            self._place(origin, now, out)
        elif self.since is not None and self._ready(now):
            self._place(origin, now, out)

    def _claimers(self, origin: ClaimingOrigin, now: float) -> list[str]:
        """Candidate teammates that could claim a burst (they submit programs)."""
        view = origin.view
        return [r for r in view.candidates(now) if r != origin.me and r in self.submitters]

    def _plans(self, origin: ClaimingOrigin) -> bool:
        """Whether the held burst is one a policy plans (it then claims)."""
        return origin.config.burst_claims and any(
            origin.policy_for(ap.submit).plans and not ap.submit.local_only for ap in origin.held)

    def _will_claim(self, origin: ClaimingOrigin) -> bool:
        """Whether the batch this robot holds will send a claim when placed."""
        return len(origin.held) >= 2 and self._plans(origin)

    def _start(self, origin: ClaimingOrigin, now: float, out: list[Action]) -> bool:
        """Ask the teammates before this robot that could claim, and tell those
        after it; False when there is nothing to wait for."""
        if not self._will_claim(origin):
            return False  # one program goes as it comes: its host admits it against its next best
        claimers = self._claimers(origin, now)
        earlier = tuple(r for r in claimers if r < origin.me)
        if not earlier:
            return False
        self.since, self.earlier = now, earlier
        self.wait = 2.0 * max(_latency(origin, r) for r in earlier)
        self.limit = now + self.wait + origin.config.burst_claim_wait * len(earlier)
        self.check = self.limit
        for r in claimers:
            out.append(Send(to=r, msg=BurstClaim(planned=False)))
        return True

    def _ready(self, now: float) -> bool:
        """Whether every teammate before this robot has answered since it
        asked (or claimed just before), and none is still planning, or the wait is over."""
        assert self.since is not None
        if now >= self.limit - 1e-12:
            return True
        recent, answered, bursting = self.since - self.wait, self.answered, self.bursting
        return all(answered.get(r, -1.0) >= max(recent, bursting.get(r, -1.0)) for r in self.earlier)

    def _place(self, origin: ClaimingOrigin, now: float, out: list[Action]) -> None:
        """Place the held burst counting the claims heard, then claim its pools."""
        plans = self._plans(origin)
        held = list(origin.held)
        origin.claimed = self.claimed(origin, now) if plans else {}
        try:
            place_held(origin, now, out)
        finally:
            origin.claimed = {}
            self.since = self.check = None
        if not plans or len(held) < 2:
            return  # one program: a claim for it would cost a message per teammate and program
        others = self._claimers(origin, now)
        if not others:
            return
        pools: dict[tuple[str, str], list[float]] = {}
        for ap in held:
            if ap.state not in FINAL and ap.host is not None:
                pools.setdefault((ap.host, ap.accelerator), []).append(ap.work)
        mine = sum(len(w) for (h, _), w in pools.items() if h == origin.me)
        claim = BurstClaim(planned=True, accepted=self.executor.accepted_total + mine,
                           pools=[ClaimedPool(h, k, w) for (h, k), w in pools.items()])
        for r in others:
            out.append(Send(to=r, msg=claim))

    def claimed(self, origin: ClaimingOrigin, now: float) -> dict[tuple[str, str], list[float]]:
        """The work the claims of the last ``KEEP`` seconds put on each pool
        that this origin's view does not show yet: on this robot, less the
        claimer's programs it runs that started since; on the claimer, unless
        a report of it has reached the claim's ``accepted`` count; on another
        robot, less as many programs as its reports have accepted since the
        claims came (the claims there in the order they came)."""
        out: dict[tuple[str, str], list[float]] = {}
        elsewhere: dict[str, list[tuple[float, int, str, list[float]]]] = {}
        for sender, (at, msg, bases) in self.heard.items():
            if at < now - KEEP or sender == origin.me or sender not in self.submitters:
                continue
            lat = _latency(origin, sender)
            here = [job.accelerator for job in self.executor.running.values()
                    if job.origin == sender and job.started_at >= at - 2.0 * lat]
            for pool in msg.pools:
                work = list(pool.work)
                if pool.robot == origin.me:
                    work = work[here.count(pool.kind):]
                elif pool.robot == sender:
                    report = origin.view.report_of(sender)
                    if report is not None and report.accepted_total >= msg.accepted:
                        continue
                else:
                    elsewhere.setdefault(pool.robot, []).append((at, bases[pool.robot], pool.kind, work))
                    continue
                if work:
                    out.setdefault((pool.robot, pool.kind), []).extend(work)
        for robot, claims in elsewhere.items():
            report = origin.view.report_of(robot)
            claims.sort(key=lambda c: c[0])
            known = [c[1] for c in claims if c[1] >= 0]
            shown = 0 if report is None or not known else max(0, report.accepted_total - min(known))
            for _, _, kind, work in claims:
                left = work[shown:]
                shown = max(0, shown - len(work))
                if left:
                    out.setdefault((robot, kind), []).extend(left)
        return out


def _latency(origin: ClaimingOrigin, robot: str) -> float:
    """One way to ``robot``, as this origin knows the link."""
    links = origin.links
    return (links.estimate(robot) if links is not None else origin.net).latency
