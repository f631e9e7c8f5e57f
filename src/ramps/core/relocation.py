"""Relocation after placement: when a running program should move, and where.

How this works: every ``relocate_period`` (policies that relocate) the
origin calls ``relocation_check``, which re-evaluates the paper's eq. (1)
for its running programs with what it knows now (fresh reports with the
hosts' work-left estimates, learned work, measured links). Its estimate of
how far a program is comes from the program's own progress when it reports
any, and from processor sharing at its host's reported load otherwise. A
program moves when its remaining time where it runs exceeds the time to
finish on the best other robot (from scratch, or from its last checkpoint,
plus T_comm of parameters and checkpoint) by ``relocate_gain`` and
``relocate_min_gain`` together (``worth_moving``), and has for
``relocate_persist`` seconds (a brief spike of load moves nothing); at most
``relocate_max_moves`` times, never within ``relocate_settle`` of an
acceptance, at most one program off a host per check. ``price_move`` asks
the program's policy for the best other host with a generator of the
origin's own for relocation, so turning relocation on leaves every
placement's draws unchanged. A move found worth it is the ``relocate``
event of the program's state machine; the move itself (``MOVING``, the old
copy running until the new host accepts) is the origin's.

Rules: functions of the ``Origin`` they decide for (they read its view,
policies and programs, and step programs through its table); no clock, no
I/O.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import msgspec

from ramps.core.cost import program_share, shared_finish_time
from ramps.core.events import Action
from ramps.core.policy import Placement, PlacementRequest
from ramps.core.program import AutonomousProgram, Event, ProgramState

if TYPE_CHECKING:
    from ramps.core.origin import Origin

S = ProgramState
#: most running programs one relocation check prices against the team (the
#: longest remaining first), so a check stays cheap with thousands running
RELOCATE_BATCH = 8


def relocation_check(origin: Origin, now: float, out: list[Action]) -> bool:
    """Re-evaluate eq. (1) for ``origin``'s running programs (see the module
    docstring). Returns whether any program may still move later."""
    rows = {row[0]: row for row in origin.view.scan(now, frozenset())}
    cfg = origin.config
    keep = False
    # the fastest a new program could run anywhere by the count of tasks
    # (the policy's first estimate): a program that would not gain by the
    # thresholds even at that rate is not priced (most checks in a
    # balanced team end here, at O(programs))
    best_rate = max((speed * program_share(cores, ramps + 1.0, background, weight)
                     for _, cores, speed, ramps, background, weight in rows.values()), default=0.0)
    if best_rate <= 0.0:
        return any(ap.state is S.RUNNING or ap.state is S.MOVING for ap in origin.programs.values())
    priced: list[tuple[float, AutonomousProgram]] = []
    for ap in origin.programs.values():
        if ap.state is not S.RUNNING and ap.state is not S.MOVING:
            continue
        policy = origin._policies[ap.submit.policy] if ap.submit.policy else origin.policy
        if not policy.relocates or ap.submit.local_only or ap.moves >= cfg.relocate_max_moves:
            continue
        keep = True
        row = rows.get(ap.host or "")
        if row is None:
            continue  # its host is suspect or gone quiet: failure detection's business
        _, cores, speed, ramps, background, weight = row
        ap.done = min(ap.work, ap.done + max(0.0, now - ap.done_at)
                      * speed * program_share(cores, max(1.0, ramps), background, weight))
        ap.done_at = now
        if ap.state is not S.RUNNING or len(ap.live) != 1 or now - ap.accepted_at < cfg.relocate_settle:
            continue
        age = origin.view.report_age(ap.placed_host, now)
        if ap.host != origin.me and (age is None or now - age < ap.accepted_at):
            continue  # no report of its host since it started there
        left = max(0.0, ap.work - ap.done)
        t_floor = origin.work_estimate(ap.submit) * (
            1.0 - (ap.checkpoint_fraction if ap.checkpoint is not None else 0.0)) / best_rate
        rate = speed * program_share(cores, max(1.0, ramps), background, weight)
        if not worth_moving(origin, left / rate, t_floor):
            ap.move_wanted_since = None
            continue  # not even by the count of tasks here (an upper bound of the estimate below)
        others = origin.view.remaining_work(ap.placed_host, now, round(ramps), ap.work) or []
        if others:  # one of them is this program: the one closest to its estimate
            others.pop(min(range(len(others)), key=lambda i: abs(others[i] - left)))
        t_here = shared_finish_time(left, others, cores, speed, background, weight)
        if not worth_moving(origin, t_here, t_floor):
            ap.move_wanted_since = None
        elif ap.move_wanted_since is None:
            ap.move_wanted_since = now  # a load spike must last before a program moves for it
        if ap.move_wanted_since is not None and now - ap.move_wanted_since >= cfg.relocate_persist:
            priced.append((t_here, ap))
    priced.sort(key=lambda x: -x[0])
    moved_off: set[str] = set()
    for t_here, ap in priced[:RELOCATE_BATCH]:
        if ap.host in moved_off:
            continue  # one at a time off a host: the next check sees it lighter
        placement = price_move(origin, ap, t_here, now)
        if placement is not None:
            moved_off.add(ap.host or "")
            origin._step(ap, Event.RELOCATE, now, out, placement)
    return keep

def price_move(origin: Origin, ap: AutonomousProgram, t_here: float, now: float) -> Placement | None:
    """Where ``ap`` would finish sooner by the relocation thresholds, or None."""
    sub = ap.submit
    work = origin.work_estimate(sub) * (1.0 - (ap.checkpoint_fraction if ap.checkpoint is not None else 0.0))
    policy = origin._policies[sub.policy] if sub.policy else origin.policy
    placement = policy.choose(
        PlacementRequest(program_id=ap.program_id, work=work,
                         payload_size=sub.payload_size + len(ap.checkpoint or b""), result_size=sub.result_size),
        origin.view, now, origin._reloc_rng, net=origin.net, config=origin.config,
        exclude=frozenset({ap.host or ""}) | origin.view.short_of_memory(sub.memory)
        | origin.relink.excluded(origin.view.robots(), now),
        links=origin.links.estimate if origin.links is not None else None,
    )
    t_there = placement.expected_time
    if placement.host == ap.host or t_there is None or not worth_moving(origin, t_here, t_there):
        return None
    cfg = origin.config
    # the new host takes it if it finishes there within what staying costs
    # (less the thresholds), whatever the origin's view missed
    budget = t_here / (1.0 + cfg.relocate_gain)
    if placement.time_budget is not None:
        budget = min(budget, placement.time_budget)
    return msgspec.structs.replace(placement, time_budget=budget)

def worth_moving(origin: Origin, t_here: float, t_there: float) -> bool:
    """Eq. (1) with hysteresis: the relative AND the absolute gain."""
    cfg = origin.config
    return t_here > t_there * (1.0 + cfg.relocate_gain) and t_here - t_there > cfg.relocate_min_gain
