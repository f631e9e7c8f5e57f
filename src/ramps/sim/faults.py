"""Faults in the simulator (``ramps.sim.engine``): a crash, a cut, a freeze,
a battery's charge, background load, and recovery; and the liveliness
notices that tell the teammates, as Zenoh does.

Rules: only the simulator's own state changes; every decision is its nodes'.
"""

from __future__ import annotations

import math
from typing import Any, Callable, Protocol

from ramps.core.durable import decode_record, encode_record, program_of, record_of
from ramps.core.events import PeerAlive, PeerLost
from ramps.core.program import FINAL
from ramps.sim.cpu import set_frozen
from ramps.sim.results import TraceEntry
from ramps.sim.scenario import FaultSpec

_Robot = Any  # ``ramps.sim.engine._Robot``


class Simulator(Protocol):
    """What a fault reads and calls of ``ramps.sim.engine.Simulator``."""

    now: float
    robots: dict[str, Any]
    records: dict[str, Any]
    trace: list[TraceEntry]
    net: Any
    batteries: Any
    _trace_on: bool
    _pending: int

    def _at(self, t: float, fn: Callable[..., None], arg: Any = None) -> None: ...

    def _handle(self, r: Any, event: Any) -> None: ...

    def _apply(self, r: Any, actions: list[Any]) -> None: ...

    def _boot(self, r: Any, now: float) -> None: ...

    def _cpu_changed(self, r: Any) -> None: ...


def apply_fault(sim: Simulator, f: FaultSpec) -> None:
    """A fault of the scenario happens now (see ``ramps.sim.engine``)."""
    r = sim.robots[f.robot]
    if sim._trace_on:
        sim.trace.append(TraceEntry(sim.now, f.robot, "fault", "", "", 0, f.kind))
    if f.kind == "crash" and r.alive:
        r.alive = False
        r.epoch += 1
        if r.spec.record:  # what the node had written, as bytes, as the runtime's store keeps them
            r.record = [encode_record(record_of(ap)) for ap in r.node.origin.programs.values()
                        if ap.state not in FINAL]
        else:
            _orphan_programs_of(sim, r)
        _liveliness(sim, r, lost=True, delay=sim.net.crash_detect)
    elif f.kind == "network" and r.alive and r.net_up:
        r.net_up = False
        r.epoch += 1
        _liveliness(sim, r, lost=True, delay=sim.net.lease)
    elif f.kind == "freeze" and r.alive and not r.frozen:
        r.frozen = True
        r.epoch += 1
        set_frozen((r.cpu, *r.accel.values()), True, sim.now)
        _liveliness(sim, r, lost=True, delay=sim.net.lease)
    elif f.kind == "battery":
        sim.batteries.set_charge(f.robot, r.cpu, sim.now, f.charge or 0.0)
    elif f.kind == "load":
        if r.alive and f.background is not None:
            r.cpu.set_background(f.background, sim.now)
            r.node.executor.background = float(f.background)
            sim._cpu_changed(r)
    elif f.kind == "recover":
        if not r.alive:
            sim._boot(r, sim.now)
            if r.record:
                out: list = []
                r.node.origin.restore([program_of(decode_record(b), sim.now) for b in r.record], sim.now, out)
                r.record = []
                sim._apply(r, out)
        else:
            if r.frozen:
                r.frozen = False
                set_frozen((r.cpu, *r.accel.values()), False, sim.now)
                sim._cpu_changed(r)
                r.wake_at = math.inf
                sim._apply(r, [])  # its timers' wake
            r.net_up = True
        _liveliness(sim, r, lost=False, delay=sim.net.crash_detect)


def _orphan_programs_of(sim: Simulator, r: _Robot) -> None:
    """A crashed origin's programs are nobody's concern any more (paper 3.3)."""
    for rec in sim.records.values():
        if rec.origin == r.spec.name and rec.deliveries == 0 and not rec.error:
            rec.error = "origin crashed"
            sim._pending -= 1


def _liveliness(sim: Simulator, r: _Robot, *, lost: bool, delay: float) -> None:
    if sim.net.liveliness:
        sim._at(sim.now + delay, lambda arg: _notify_liveliness(sim, arg), (r, lost))


def _notify_liveliness(sim: Simulator, arg: tuple[_Robot, bool]) -> None:
    r, lost = arg
    name = r.spec.name
    if lost and r.reachable:
        return  # it came back before anybody noticed
    for other in sim.robots.values():
        if other is r or not other.alive or other.frozen:
            continue
        if lost:
            if other.net_up:
                sim._handle(other, PeerLost(robot=name))
            if r.alive and not r.net_up and not r.frozen:
                sim._handle(r, PeerLost(robot=other.spec.name))
        elif r.reachable and other.reachable:
            sim._handle(other, PeerAlive(robot=name))
            sim._handle(r, PeerAlive(robot=other.spec.name))
