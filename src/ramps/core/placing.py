"""Placing a program's next attempt: where it goes, and the offer that takes it there.

How this works: ``place`` makes a program's next attempt. The host is the
one it is told (``local_only``, an isolated origin's own robot), the one a
relocation priced (``Placement``), or the one its policy chooses from the
origin's load view: the work is what the origin learned of the program
(``ramps.core.learning``), less what its latest checkpoint saved; robots are
excluded by ``exclusions`` (those the program failed or was turned away
on, short of memory, low on battery, relinking after this robot's stall,
and, for a program that may not run on a CPU, every robot without its
accelerator). A deadline the policy cannot meet goes to
``ramps.core.deadlines``. The attempt is booked in the view at once (so
the next placement sees it), indexed by host, and offered (``offer``:
``OffloadRequest`` with the latest checkpoint); its connect timeout allows
for the parameters of this robot's other offers to that host still
crossing the link.

Rules: functions of the origin they place for, which they see as a
``PlacingOrigin``; no clock, no I/O, the policy's draws from the origin's
``rng``.
"""

from __future__ import annotations

import random
from typing import Protocol

from ramps.core import deadlines
from ramps.core.config import RampsConfig
from ramps.core.cost import NetworkEstimate
from ramps.core.events import Action, Note, Send, Submit
from ramps.core.links import Links
from ramps.core.loadview import LoadView
from ramps.core.messages import OffloadRequest
from ramps.core.policy import Placement, PlacementRequest, Policy
from ramps.core.program import AutonomousProgram, Event, ProgramState
from ramps.core.relink import Relink
from ramps.core.timers import Timers

S = ProgramState


class PlacingOrigin(deadlines.DeliveringOrigin, Protocol):
    """What placing reads and changes of ``ramps.core.origin.Origin``."""

    view: LoadView
    config: RampsConfig
    rng: random.Random
    net: NetworkEstimate
    links: Links | None
    relink: Relink
    programs: dict[str, AutonomousProgram]
    #: host -> the ids of its live programs, in placement order
    by_host: dict[str, dict[str, None]]
    #: teammate -> ids of the programs offered to it: every one still offered there, and some no longer
    offered: dict[str, dict[str, None]]
    hosts_of: dict[str, set[str]]
    timers: Timers
    stalled_s: float
    placements: int
    #: (robot, accelerator kind) -> work teammates' bursts claimed there (``ramps.core.claims``)
    claimed: dict[tuple[str, str], list[float]]

    def work_estimate(self, sub: Submit) -> float: ...

    def accelerator_work_estimate(self, sub: Submit) -> float: ...

    def policy_for(self, sub: Submit) -> Policy: ...

    def backoff(self, ap: AutonomousProgram, now: float, out: list[Action], *, certain: bool = False) -> None: ...


def place(origin: PlacingOrigin, ap: AutonomousProgram, now: float, out: list[Action], *, host: str | None = None,
          placement: Placement | None = None, prefer: tuple[str, float] = ("", 0.0)) -> None:
    """Offer ``ap``'s next attempt: to ``host``, where a relocation's
    ``placement`` says, or where its policy chooses (``prefer``: the host
    a burst's plan chose for it and the plan's end, ``ramps.core.burst``)."""
    sub = ap.submit
    resume = ap.checkpoint
    fraction = ap.checkpoint_fraction if resume is not None else 0.0
    work = origin.work_estimate(sub) * (1.0 - fraction)  # what is left from the checkpoint
    expected = budget = deadline_in = None
    left = sub.deadline - now if sub.deadline is not None else None
    if placement is not None:  # a relocation priced it already (and tells the new host the time left)
        host, expected, budget = placement.host, placement.expected_runnable, placement.time_budget
        deadline_in = left if left is not None and (placement.expected_time or 0.0) < left else None
    if host is None and sub.local_only:
        host = origin.me
    accel_work = origin.accelerator_work_estimate(sub) * (1.0 - fraction)
    if host is None:
        policy = origin.policy_for(sub)
        exclude = exclusions(origin, ap, now, out)
        if exclude is None:
            return
        placement = policy.choose(
            request(ap, work, accel_work, left, prefer),
            origin.view, now, origin.rng, net=origin.net, config=origin.config, exclude=exclude,
            links=origin.links,
        )
        host = placement.host
        if policy.negotiates:
            expected = placement.expected_runnable
            budget = placement.time_budget
            if expected is not None and host == prefer[0] and not sub.accelerator and origin.claimed:
                # the plan counted teammates' claims there, which the view may not show yet: so does the host
                expected += len(origin.claimed.get((host, ""), ()))
        if left is not None and (placement.late or left <= 0.0):
            host = deadlines.unmet(origin, ap, placement, left, now, out)
            if host is None:
                return
            if host != placement.host:  # the policy's estimates were for its pick
                expected = budget = None
        elif left is not None and policy.negotiates:
            deadline_in = left  # the host checks it against its true load
    if ap.host is not None and ap.host not in ap.live.values():
        origin.by_host.get(ap.host, {}).pop(ap.program_id, None)
    _attempt(origin, ap, host, work, accel_work, fraction if resume is not None else None, now)
    detail = ""
    if placement is not None and placement.expected_time is not None:  # why there, for traces
        detail = f"expected {placement.expected_time:.2f} s"
        if placement.time_budget is not None:
            detail += f", budget {placement.time_budget:.2f} s"
    out.append(Note(what="placed", program_id=ap.program_id, robot=host, attempt=ap.attempt, detail=detail))
    offer(origin, ap, out, expected=expected, budget=budget, deadline_in=deadline_in)
    # the host cannot accept before the parameters have crossed the link,
    # behind those of this robot's other offers to it still on their way
    transfer = 0.0
    if host != origin.me:
        link = origin.links.estimate(host) if origin.links is not None else origin.net
        transfer = queued_bytes(origin, host) / link.bandwidth
    origin.timers.set(ap, now + origin.config.connect_timeout + transfer, Event.CONNECT_TIMEOUT)


def queued_bytes(origin: PlacingOrigin, host: str) -> int:
    """Bytes of parameters of the live programs offered to teammate ``host``
    and not accepted yet (``OFFERED`` there). Read from ``origin.offered``,
    which holds each of them (a program becomes OFFERED only by ``offer``
    or with one straight after, which adds it), so only this robot's recent
    offers to ``host`` are walked, not all its programs there; those that
    moved on are dropped from it here."""
    ids = origin.offered.get(host)
    if not ids:
        return 0
    programs, live = origin.programs, origin.by_host.get(host, {})
    queued = 0
    for pid in list(ids):
        ap = programs.get(pid)
        if ap is None or ap.state is not S.OFFERED or ap.host != host:
            del ids[pid]
        elif pid in live:
            queued += ap.submit.payload_size
    return queued


def _attempt(origin: PlacingOrigin, ap: AutonomousProgram, host: str, work: float, accel_work: float,
             resumed_from: float | None, now: float) -> None:
    """Make ``ap``'s next attempt, on ``host``, and book it there
    (``resumed_from``: the fraction its checkpoint saved; None: from the start)."""
    ap.made += 1
    ap.attempt = ap.made
    ap.host = host
    ap.live[ap.attempt] = host
    ap.state = S.OFFERED
    ap.last_heard = now
    ap.accelerator = ap.submit.accelerator if ap.submit.accelerator in origin.view.accelerator_kinds(host) else ""
    if ap.accelerator:
        work = accel_work
    ap.work, ap.done, ap.done_at = work, 0.0, now
    ap.placed_at, ap.stall_base = now, origin.stalled_s
    ap.resumed_from = resumed_from
    origin.by_host.setdefault(host, {})[ap.program_id] = None
    origin.hosts_of.setdefault(ap.program_id, set()).add(host)
    origin.view.book(host, ap.program_id, ap.attempt, ap.accelerator, work, now)
    origin.placements += 1


def request(ap: AutonomousProgram, work: float, accel_work: float, left: float | None,
            prefer: tuple[str, float] = ("", 0.0)) -> PlacementRequest:
    """What the policy is asked to place for ``ap`` (``left``: seconds to its deadline)."""
    sub = ap.submit
    return PlacementRequest(program_id=ap.program_id, work=work, deadline=left, prefer=prefer[0], plan_end=prefer[1],
                            payload_size=sub.payload_size + len(ap.checkpoint or b""), result_size=sub.result_size,
                            accelerator=sub.accelerator, accelerator_work=accel_work)


def exclusions(origin: PlacingOrigin, ap: AutonomousProgram, now: float,
               out: list[Action]) -> frozenset[str] | None:
    """The robots ``ap`` may not go to now; None when there is nowhere
    it may (it then waits or failed, ``_without_accelerator``)."""
    sub = ap.submit
    view = origin.view
    exclude = (frozenset(ap.excluded) | view.short_of_memory(sub.memory) | view.low_battery
               | origin.relink.excluded(view.robots(), now))
    if sub.accelerator and not sub.cpu_fallback:
        return _without_accelerator(origin, ap, exclude, now, out)
    return exclude


def _without_accelerator(origin: PlacingOrigin, ap: AutonomousProgram, exclude: frozenset[str], now: float,
                         out: list[Action]) -> frozenset[str] | None:
    """``exclude`` plus every robot without the accelerator ``ap`` needs
    (it may not run on a CPU). None when no candidate has one: the
    program waits for one (a robot that advertised the kind is away) or,
    if no robot of the team ever advertised it, fails at once."""
    kind = ap.submit.accelerator
    robots = origin.view.robots()
    having = [r for r in robots if kind in origin.view.accelerator_kinds(r)]
    if origin.view.accelerator_rows(now, kind, exclude):
        return exclude | frozenset(r for r in robots if r not in having)
    if not having:
        origin.deliver(ap, now, out, ok=False, kind="refused",
                       error=f"{ap.submit.program} needs a {kind!r} accelerator and no robot of the team "
                             f"advertises one (start a node with --accelerator {kind}, or let the "
                             f"program run on a CPU)")
        return None
    ap.failures += 1  # each wait counts towards max_attempts
    origin.backoff(ap, now, out)
    return None


def offer(origin: PlacingOrigin, ap: AutonomousProgram, out: list[Action], *, expected: float | None = None,
          budget: float | None = None, deadline_in: float | None = None) -> None:
    """Send the current attempt's offer (``OffloadRequest``) to its host,
    with its latest checkpoint: what is left of the work from there."""
    sub = ap.submit
    resume = ap.checkpoint
    if ap.placed_host != origin.me:
        origin.offered.setdefault(ap.placed_host, {})[ap.program_id] = None
        origin.hosts_of.setdefault(ap.program_id, set()).add(ap.placed_host)
    out.append(Send(to=ap.placed_host, msg=OffloadRequest(
        program_id=ap.program_id, attempt=ap.attempt, origin=origin.me, host=ap.placed_host,
        program=sub.program, args=sub.args, payload_size=sub.payload_size, work=ap.work,
        expected_runnable=expected, time_budget=budget, force=ap.rejections >= origin.config.max_rejections,
        resume=resume, resume_fraction=ap.checkpoint_fraction if resume is not None else 0.0,
        deadline_in=deadline_in, accelerator=ap.accelerator,
    )))
