"""Placement policies: where an autonomous program goes.

Rules: a policy is a strategy object with one method, ``choose``, that reads
the origin's load view and returns a ``Placement``. It never changes the view
(the origin books the placement afterwards) and takes all randomness from
the ``rng`` it is given. Each origin holds its own policy instance, so each
robot decides for its own programs from its own view: there is no central
scheduler.

* ``paper``: the prototype of Valkov et al.: cost from the last report's CPU
  load (which saturates at 100%) plus bookings this robot made since that
  report; the next report overwrites the bookings; every executor, the local
  one included, costs the same T_comm (the prototype offloaded to its own
  executor through the same action protocol); ties are broken at random.
* ``ramps``: our default. Cost from run-queue length (8 stress processes look
  like 8, not like "100%"), ramps programs counted from bookings until a
  report proves it includes them, eq. (1) with T_comm for remote hosts only;
  costs within ``tie_tolerance`` are equal, and the tie goes to the least
  utilised robot, then to the local one. The host checks the origin's
  estimate when the request arrives (``expected_runnable``) and turns the
  program away if it is busier than the origin thought, which fixes the
  greedy "location thrashing" of several origins deciding on the same data.
* ``round_robin``, ``random``, ``local_only``: baselines.
"""

from __future__ import annotations

import random
from typing import ClassVar

import msgspec

from ramps.core.config import RampsConfig
from ramps.core.cost import HostEstimate, NetworkEstimate, estimate
from ramps.core.loadview import LoadView


class PlacementRequest(msgspec.Struct, frozen=True, kw_only=True):
    program_id: str
    work: float
    payload_size: int
    result_size: int


class Placement(msgspec.Struct, frozen=True, kw_only=True):
    host: str
    #: runnable tasks the origin expects on the host (ramps negotiation)
    expected_runnable: float | None = None
    #: estimated seconds to completion there, for traces
    expected_time: float | None = None


class Policy:
    name: ClassVar[str] = ""
    #: whether hosts should check ``expected_runnable`` on arrival
    negotiates: ClassVar[bool] = False

    def choose(
        self,
        req: PlacementRequest,
        view: LoadView,
        now: float,
        rng: random.Random,
        *,
        net: NetworkEstimate,
        config: RampsConfig,
        exclude: frozenset[str] = frozenset(),
    ) -> Placement:
        raise NotImplementedError

    @staticmethod
    def _candidates(view: LoadView, now: float, exclude: frozenset[str]) -> list[str]:
        cands = view.candidates(now)
        if exclude:
            kept = [c for c in cands if c not in exclude]
            if kept:
                return kept
        return cands


class PaperPolicy(Policy):
    name = "paper"

    def choose(self, req, view, now, rng, *, net, config, exclude=frozenset()):
        best: list[HostEstimate] = []
        for robot in self._candidates(view, now, exclude):
            cores, speed = view.capacity(robot)
            est = estimate(
                robot, local=False, cores=cores, speed=speed, runnable=view.paper_load(robot),
                work=req.work, payload=req.payload_size, result=req.result_size, net=net,
            )
            if not best or est.total < best[0].total - 1e-9:
                best = [est]
            elif abs(est.total - best[0].total) <= 1e-9:
                best.append(est)
        pick = best[0] if len(best) == 1 else rng.choice(best)
        return Placement(host=pick.robot, expected_time=pick.total)


class RampsPolicy(Policy):
    name = "ramps"
    negotiates = True

    def choose(self, req, view, now, rng, *, net, config, exclude=frozenset()):
        ests: list[HostEstimate] = []
        me = view.me
        for robot in self._candidates(view, now, exclude):
            cores, speed = view.capacity(robot)
            runnable = view.background(robot) + view.ramps_programs(robot)
            ests.append(
                estimate(
                    robot, local=robot == me, cores=cores, speed=speed, runnable=runnable,
                    work=req.work, payload=req.payload_size, result=req.result_size, net=net,
                )
            )
        t_best = min(e.total for e in ests)
        limit = t_best * (1.0 + config.tie_tolerance) + 1e-9
        tied = [e for e in ests if e.total <= limit]
        # least utilised first, then local (no network), then at random
        u_best = min(e.utilisation_after for e in tied)
        tied = [e for e in tied if e.utilisation_after <= u_best + 1e-9]
        local = [e for e in tied if e.local]
        pick = local[0] if local else (tied[0] if len(tied) == 1 else rng.choice(tied))
        return Placement(host=pick.robot, expected_runnable=pick.runnable, expected_time=pick.total)


class RoundRobinPolicy(Policy):
    name = "round_robin"

    def __init__(self) -> None:
        self._next = 0

    def choose(self, req, view, now, rng, *, net, config, exclude=frozenset()):
        cands = self._candidates(view, now, exclude)
        ring = [view.me] + sorted(c for c in cands if c != view.me)
        host = ring[self._next % len(ring)]
        self._next += 1
        return Placement(host=host)


class RandomPolicy(Policy):
    name = "random"

    def choose(self, req, view, now, rng, *, net, config, exclude=frozenset()):
        cands = self._candidates(view, now, exclude)
        return Placement(host=rng.choice(sorted(cands)))


class LocalOnlyPolicy(Policy):
    name = "local_only"

    def choose(self, req, view, now, rng, *, net, config, exclude=frozenset()):
        return Placement(host=view.me)


POLICIES: dict[str, type[Policy]] = {
    p.name: p for p in (RampsPolicy, PaperPolicy, RoundRobinPolicy, RandomPolicy, LocalOnlyPolicy)
}


def make_policy(name: str) -> Policy:
    try:
        return POLICIES[name]()
    except KeyError:
        raise ValueError(f"unknown policy {name!r}; choose one of {', '.join(POLICIES)}") from None
