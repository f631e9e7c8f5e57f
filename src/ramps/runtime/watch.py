"""Watching a team from outside: who is alive and what each robot last reported.

How this works: ``TeamWatcher`` holds one Zenoh session (its own, from
``TeamWatcher.open(config, team)``, or one it is handed) and two
subscribers: the team's liveliness tokens (``ramps/<team>/alive/*``, with
history, so robots already up count at once) and its load reports
(``ramps/<team>/load/*``). The Zenoh callbacks only record, under one
condition variable: the alive set, the latest report of each robot with the
monotonic time it arrived, and every liveliness change with its time (for
detection-time measurements). Readers take copies under the same condition;
``wait`` sleeps on it until a robot comes or goes.

Rules: a report is kept only when its robot is its sender (a node speaks for
itself); anything that does not decode is ignored, never raised. ``close()``
undeclares the subscribers, and closes the session only if the watcher
opened it.

One watcher for the tools that watch a team: the flood benchmark, the
testbed (``ramps.testbed.bed.watch_team``: readiness, status, experiments)
and the detection-time tool all use it.
"""

from __future__ import annotations

import threading
import time
from typing import Any

from ramps.core import messages as m
from ramps.runtime import keys

__all__ = ["TeamWatcher"]


class TeamWatcher:
    def __init__(self, session: Any, team: str, *, own_session: bool = False) -> None:
        import zenoh

        self._put = zenoh.SampleKind.PUT
        self.team = team
        self.session = session
        self._own_session = own_session
        self.cv = threading.Condition()
        self.alive: set[str] = set()
        self.reports: dict[str, tuple[m.LoadReport, float]] = {}
        #: every liveliness change: (monotonic time, robot, alive)
        self.events: list[tuple[float, str, bool]] = []
        self._subs: list[Any] = []
        try:
            self._subs.append(session.liveliness().declare_subscriber(keys.alive(team), self._on_alive,
                                                                      history=True))
            self._subs.append(session.declare_subscriber(keys.load(team), self._on_report))
        except BaseException:
            self.close()
            raise

    @classmethod
    def open(cls, config: Any, team: str) -> TeamWatcher:
        """A watcher with a session of its own, opened with this Zenoh config."""
        import zenoh

        return cls(zenoh.open(config), team, own_session=True)

    # ------------------------------------------------------------ callbacks (record only)
    def _on_alive(self, sample: Any) -> None:
        now = time.monotonic()
        robot = keys.robot_of(str(sample.key_expr))
        put = sample.kind == self._put
        with self.cv:
            self.events.append((now, robot, put))
            (self.alive.add if put else self.alive.discard)(robot)
            self.cv.notify_all()

    def _on_report(self, sample: Any) -> None:
        try:
            env = m.decode(sample.payload.to_bytes())
        except m.WireError:
            return
        if isinstance(env.msg, m.LoadReport) and env.msg.robot == env.sender:
            with self.cv:
                self.reports[env.msg.robot] = (env.msg, time.monotonic())
                self.cv.notify_all()

    # ------------------------------------------------------------ reading
    def report(self, robot: str) -> m.LoadReport | None:
        """The latest load report of ``robot``, or None."""
        with self.cv:
            rep = self.reports.get(robot)
        return rep[0] if rep else None

    def bad_messages(self, robot: str) -> int | None:
        """How many malformed messages ``robot`` says it dropped, or None before its first report."""
        rep = self.report(robot)
        return None if rep is None else rep.bad_messages

    def ready(self) -> set[str]:
        """Robots alive that have published load since this watcher opened."""
        with self.cv:
            return self.alive & set(self.reports)

    def view(self) -> list[dict[str, Any]]:
        """One row per robot seen: alive, and what its last report said."""
        now = time.monotonic()
        with self.cv:
            rows = []
            for r in sorted(self.alive | set(self.reports)):
                rep, at = self.reports.get(r, (None, now))
                row: dict[str, Any] = dict(robot=r, alive=r in self.alive)
                if rep is not None:
                    row.update(cores=rep.cores, speed=rep.speed, cpu_busy=rep.cpu_busy, runnable=rep.runnable,
                               running=rep.ramps_running, sees=rep.sees, report_age=round(now - at, 3))
                rows.append(row)
            return rows

    def wait(self, robot: str, alive: bool, timeout: float, since: float | None = None) -> float | None:
        """Time of the first liveliness PUT (``alive``) or DELETE of ``robot``
        at or after ``since``; with no ``since``, now if the robot already is
        so. None after ``timeout`` seconds."""
        deadline = time.monotonic() + timeout
        with self.cv:
            while True:
                if since is None and (robot in self.alive) == alive:
                    return time.monotonic()
                for t, r, put in self.events:
                    if since is not None and t >= since and r == robot and put == alive:
                        return t
                left = deadline - time.monotonic()
                if left <= 0:
                    return None
                self.cv.wait(left)

    # ------------------------------------------------------------ closing
    def close(self) -> None:
        try:
            for sub in self._subs:
                try:
                    sub.undeclare()
                except Exception:
                    pass
            self._subs.clear()
        finally:
            if self._own_session:
                self._own_session = False
                self.session.close()

    def __enter__(self) -> TeamWatcher:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
