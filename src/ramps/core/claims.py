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
  whose reports of the instant say an application submits there,
  ``LoadReport.submits``);
- else tells the teammates after it that could claim that it has a burst
  (``BurstClaim``, ``planned`` False) and holds it: ``wait`` (twice the
  link's latency: a claim of the same instant has come by then) to hear
  which teammates before it have one, then until each of them has sent
  where its programs went (``planned`` True), at most ``wait`` more per
  teammate before it.

Once placed, an origin sends the teammates after it that could claim
where its burst of two programs or more went: the work it put on each pool
(robot, accelerator kind). A plan counts a claim as work on its pools
(``claimed``, ``Pool.known``) until the view shows it: on this robot, as
the claimer's programs start here; on the claimer, once its reports reach
the claim's ``accepted`` count; elsewhere, once a report comes a latency
after the claim. An origin none of whose teammates submit never waits.

Rules: no clock (``now`` comes in), no I/O.
"""

from __future__ import annotations

from typing import Protocol

from ramps.core.burst import BurstOrigin, place_held
from ramps.core.events import Action, Send
from ramps.core.executor import Executor
from ramps.core.messages import BurstClaim, ClaimedPool
from ramps.core.program import FINAL


class ClaimingOrigin(BurstOrigin, Protocol):
    """What claims read and change of ``ramps.core.origin.Origin``."""

    me: str
    claimed: dict[tuple[str, str], list[float]]


class Claims:
    """The claims this robot heard, and the wait of its own burst
    (``executor``: this robot's, whose programs a claim on it may be)."""

    def __init__(self, executor: Executor) -> None:
        self.executor = executor
        #: robot -> (when its latest claim came, the claim)
        self.heard: dict[str, tuple[float, BurstClaim]] = {}
        #: when this robot's held burst began to wait (None: it does not)
        self.since: float | None = None
        #: the teammates before this robot that could claim, when it began
        self.earlier: tuple[str, ...] = ()
        #: how long a claim of the same instant takes to come, at most (twice the latency)
        self.wait = 0.0
        #: when to look again while waiting (``Node.next_deadline``)
        self.check: float | None = None
        #: teammates whose reports say an application submits there
        self.submitters: set[str] = set()

    def on_claim(self, origin: ClaimingOrigin, sender: str, msg: BurstClaim, now: float, out: list[Action]) -> None:
        """A teammate's claim came: kept, and the burst held for it placed if it was the last awaited."""
        self.heard[sender] = (now, msg)
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
        elif self.since is not None and self._ready(origin, now):
            self._place(origin, now, out)

    def _claimers(self, origin: ClaimingOrigin, now: float) -> list[str]:
        """Candidate teammates that could claim a burst (they submit programs)."""
        view = origin.view
        return [r for r in view.candidates(now) if r != origin.me and r in self.submitters]

    def _plans(self, origin: ClaimingOrigin) -> bool:
        """Whether the held burst is one a policy plans (it then claims)."""
        return origin.config.burst_claims and any(
            origin.policy_for(ap.submit).plans and not ap.submit.local_only for ap in origin.held)

    def _start(self, origin: ClaimingOrigin, now: float, out: list[Action]) -> bool:
        """Begin the wait for the claims before this robot's; False when
        there is nothing to wait for."""
        if not self._plans(origin) or len(origin.held) < 2:
            return False  # one program goes as it comes: its host admits it against its next best
        claimers = self._claimers(origin, now)
        earlier = tuple(r for r in claimers if r < origin.me)
        if not earlier:
            return False
        self.since, self.earlier = now, earlier
        self.wait = 2.0 * max(_latency(origin, r) for r in earlier)
        self.check = now + self.wait
        for r in claimers:
            if r > origin.me:
                out.append(Send(to=r, msg=BurstClaim(planned=False)))
        return True

    def _ready(self, origin: ClaimingOrigin, now: float) -> bool:
        """Whether every claim before this robot's that may come has come, or
        the wait is over."""
        assert self.since is not None
        last = self.since + self.wait * (1 + len(self.earlier))
        if now >= last - 1e-12:
            return True
        recent = self.since - self.wait
        bursting = [r for r in self.earlier if r in self.heard and self.heard[r][0] >= recent]
        if any(not self.heard[r][1].planned for r in bursting):
            self.check = last
            return False
        if len(bursting) == len(self.earlier) or now >= self.since + self.wait - 1e-12:
            return True
        self.check = self.since + self.wait
        return False

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
        later = [r for r in self._claimers(origin, now) if r > origin.me]
        if not later:
            return
        pools: dict[tuple[str, str], list[float]] = {}
        for ap in held:
            if ap.state not in FINAL and ap.host is not None:
                pools.setdefault((ap.host, ap.accelerator), []).append(ap.work)
        mine = sum(len(w) for (h, _), w in pools.items() if h == origin.me)
        claim = BurstClaim(planned=True, accepted=self.executor.accepted_total + mine,
                           pools=[ClaimedPool(h, k, w) for (h, k), w in pools.items()])
        for r in later:
            out.append(Send(to=r, msg=claim))

    def claimed(self, origin: ClaimingOrigin, now: float) -> dict[tuple[str, str], list[float]]:
        """The work the recent claims put on each pool that this origin's
        view does not show yet: on this robot, less the claimer's programs
        it runs that started since; on the claimer, unless a report of it
        has reached the claim's ``accepted`` count; on another robot, unless
        a report of it came a latency after the claim (made after the
        claim's offers reached it)."""
        out: dict[tuple[str, str], list[float]] = {}
        horizon = (self.since if self.since is not None else now) - max(self.wait, 2.0 * origin.net.latency)
        for sender, (at, msg) in self.heard.items():
            if at < horizon or not msg.planned or sender == origin.me or sender not in self.submitters:
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
                    age = origin.view.report_age(pool.robot, now)
                    if age is not None and now - age >= at + _latency(origin, pool.robot) - 1e-9:
                        continue
                if work:
                    out.setdefault((pool.robot, pool.kind), []).extend(work)
        return out


def _latency(origin: ClaimingOrigin, robot: str) -> float:
    """One way to ``robot``, as this origin knows the link."""
    links = origin.links
    return (links.estimate(robot) if links is not None else origin.net).latency
