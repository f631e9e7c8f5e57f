"""``FakeTeam``: real core nodes joined by an in-memory network, for tests.

``FakeTeam`` joins several ``ramps.core.node.Node`` objects with an in-memory
network that has no latency: a list of messages in flight, an explicit
``now``, robots whose links are cut, and messages held back on a slow link.
Tests step it by hand, so each reads as a scenario: submit, deliver,
advance the clock, finish a program, look at the actions. Nothing sleeps and
nothing is random except the nodes' own seeded generators. Because the nodes
are the real core, a test against ``FakeTeam`` exercises the same placement,
failure detection and exactly-once delivery as a real team.
"""

from __future__ import annotations

import random

from ramps.core.accelerators import Accelerator
from ramps.core.config import RampsConfig
from ramps.core.events import Action, Deliver, Note, ProgramFinished, Received, Send
from ramps.core.messages import Message
from ramps.core.node import Node
from ramps.core.program import AutonomousProgram

__all__ = ["FakeTeam"]


class FakeTeam:
    """An in-memory team: nodes by name, messages in flight, explicit ``now``.

    The network has no latency: ``deliver()`` hands every message in flight
    to its receiver, and whatever that sends, until nothing is left. A robot
    in ``cut`` neither sends nor receives. ``hold`` keeps matching messages
    aside (a slow link) until ``release()``."""

    def __init__(self, robots: dict[str, tuple[int, float]], *, policy: str = "ramps",
                 config: RampsConfig | None = None, registry: dict[str, frozenset[str]] | None = None,
                 accelerators: dict[str, list[Accelerator]] | None = None) -> None:
        self.now = 0.0
        self.nodes = {
            name: Node(name, cores=cores, speed=speed, policy=policy, config=config or RampsConfig(), rng=random.Random(i),
                       registry=(registry or {}).get(name), accelerators=(accelerators or {}).get(name, ()))
            for i, (name, (cores, speed)) in enumerate(robots.items())
        }
        self.inflight: list[tuple[str, str, Message]] = []
        self.held: list[tuple[str, str, Message]] = []
        self.cut: set[str] = set()
        #: every action any node asked for: (time, robot, action)
        self.log: list[tuple[float, str, Action]] = []

    # ---------------------------------------------------------- driving
    def apply(self, robot: str, actions: list[Action]) -> list[Action]:
        for a in actions:
            self.log.append((self.now, robot, a))
            if isinstance(a, Send) and robot not in self.cut and a.to not in self.cut:
                self.inflight.append((robot, a.to, a.msg))
        return actions

    def handle(self, robot: str, event) -> list[Action]:
        return self.apply(robot, self.nodes[robot].handle(event, self.now))

    def deliver(self, hold=None) -> None:
        while self.inflight:
            sender, to, msg = self.inflight.pop(0)
            if hold is not None and hold(sender, to, msg):
                self.held.append((sender, to, msg))
                continue
            if sender in self.cut or to in self.cut:
                continue
            self.handle(to, Received(sender=sender, msg=msg))

    def release(self) -> None:
        self.inflight.extend(self.held)
        self.held.clear()
        self.deliver()

    def advance(self, until: float, hold=None) -> None:
        """Fire every node's timers due up to ``until``, in time order."""
        for _ in range(100_000):
            due = [(d, name) for name, n in self.nodes.items()
                   if (d := n.next_deadline()) is not None and d <= until]
            if not due:
                break
            when, name = min(due)
            self.now = max(self.now, when)
            self.apply(name, self.nodes[name].tick(self.now))
            self.deliver(hold)
        else:  # pragma: no cover
            raise AssertionError("timers never settled")
        self.now = until

    def publish(self, *robots: str) -> None:
        """Each robot's load publisher reports what its executor runs now."""
        for robot in robots or tuple(self.nodes):
            n = self.nodes[robot]
            running = n.executor.cpu_programs()
            busy = n.executor.background + running
            rep = n.make_report(cpu_busy=min(float(n.cores), busy), runnable=busy,
                                ramps_avg=float(running), window=1.0)
            for name in self.nodes:
                if name == robot or (robot not in self.cut and name not in self.cut):
                    self.handle(name, Received(sender=robot, msg=rep))

    def finish(self, robot: str, program_id: str, attempt: int, **kw) -> None:
        self.handle(robot, ProgramFinished(program_id=program_id, attempt=attempt, **kw))
        self.deliver()

    # ---------------------------------------------------------- looking
    def actions(self, kind, robot: str | None = None) -> list:
        return [a for _, r, a in self.log if isinstance(a, kind) and (robot is None or r == robot)]

    def sent(self, msg_type, *, by: str | None = None, to: str | None = None) -> list:
        return [a.msg for _, r, a in self.log if isinstance(a, Send) and isinstance(a.msg, msg_type)
                and (by is None or r == by) and (to is None or a.to == to)]

    def notes(self, what: str, robot: str = "o") -> list[Note]:
        return [a for a in self.actions(Note, robot) if a.what == what]

    def delivered(self, program_id: str) -> list[Deliver]:
        return [a for a in self.actions(Deliver) if a.program_id == program_id]

    def program(self, program_id: str, origin: str = "o") -> AutonomousProgram:
        return self.nodes[origin].origin.programs[program_id]
