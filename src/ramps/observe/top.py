"""``ramps top``: a live terminal view of the team.

How this works: the client's own team watcher (``ramps.runtime.client.Team``:
liveliness tokens and load reports) is polled a few times a second; each
``TeamStatus`` goes into a ``TopModel``, which keeps every robot ever seen
(a robot that disappears stays, greyed, with how long ago it was last
heard) and turns the differences between two views into events: a robot
joining, leaving (its node stopped and handed its programs back: it said so
with its ``leaving`` token before its liveliness went), gone (its liveliness
went without that: a crash, a cut link), writing a teammate off, a
program starting on a host, finishing there (and how long it ran), and
starting again elsewhere after its host was lost (a move). ``render``
draws the model with rich; the command refreshes it in a ``rich.live.Live``.

Rules: the model is plain data fed with ``update(status, now)`` so tests
drive it with real statuses; nothing here talks to the team but through
``Team.status()``. Program ids are not in load reports: programs are told
apart by (program, origin), which is exact for counts and best effort for
naming which one moved.
"""

from __future__ import annotations

from collections import Counter, deque
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from rich.console import Group
from rich.panel import Panel
from rich.table import Table
from rich.text import Text

if TYPE_CHECKING:
    from ramps.runtime.futures import RobotStatus, TeamStatus

#: events kept for the scrolling list
MAX_EVENTS = 200


@dataclass
class RobotView:
    name: str
    status: RobotStatus  # the latest one
    alive: bool
    first_seen: float
    last_heard: float  # `now` of the newest load report (or of joining)
    gone_at: float | None = None
    #: it left (its node stopped and handed its programs back), not crashed
    left: bool = False
    #: programs seen running there when it went
    gone_programs: int = 0
    #: (program, origin) -> times each copy was first seen running here
    running: dict[tuple[str, str], list[float]] = field(default_factory=dict)


@dataclass
class TopEvent:
    t: float
    kind: str  # joined, left, gone, back, wrote_off, cleared, started, finished, stopped, moved
    robot: str
    text: str


class TopModel:
    def __init__(self, team: str = "") -> None:
        self.team = team
        self.robots: dict[str, RobotView] = {}
        self.events: deque[TopEvent] = deque(maxlen=MAX_EVENTS)
        #: programs running on a robot when it was lost: (program, origin) -> [(robot, when)]
        self._displaced: dict[tuple[str, str], list[tuple[str, float]]] = {}
        self.updates = 0
        self.started_at: float | None = None

    def _event(self, t: float, kind: str, robot: str, text: str) -> None:
        self.events.append(TopEvent(t, kind, robot, text))

    def alive(self) -> list[str]:
        return [r for r, v in self.robots.items() if v.alive]

    def update(self, status: TeamStatus, now: float) -> None:
        """One view of the team (``Team.status()``), taken at ``now`` (monotonic seconds)."""
        self.updates += 1
        if self.started_at is None:
            self.started_at = now
        self.team = status.team or self.team
        # robots lost first: a program that left one and started on another in
        # the same interval is then recognised as moved, whatever the names' order
        order = sorted(status.robots, key=lambda st: st.alive)
        live = []
        for st in order:
            heard = now - st.report_age if st.report_age is not None else None
            v = self.robots.get(st.robot)
            if v is None:
                v = self.robots[st.robot] = RobotView(st.robot, st, st.alive, now, heard or now)
                if st.alive:
                    self._event(now, "joined", st.robot, f"{st.robot} joined ({st.cores} cores, speed {st.speed:g})"
                                if st.cores else f"{st.robot} joined")
            prev = v.status
            if prev is st:  # first sight: what runs there was running before we watched
                v.running = {k: [now] * n for k, n in Counter((x.program, x.origin) for x in st.running).items()}
            if heard is not None:
                v.last_heard = max(v.last_heard, heard)
            if st.alive and not v.alive:
                v.alive, v.gone_at, v.left = True, None, False
                self._event(now, "back", st.robot, f"{st.robot} is back")
            elif not st.alive and v.alive:
                v.alive, v.gone_at, v.left = False, now, st.leaving
                v.gone_programs = sum(len(x) for x in v.running.values())
                self._event(now, *self._gone(v))
                for key, starts in v.running.items():
                    self._displaced.setdefault(key, []).extend((st.robot, now) for _ in starts)
                v.running = {}
            elif not st.alive and st.leaving and not v.left and v.gone_at is not None:
                # its goodbye came after its liveliness went: the event said "gone"; it left
                v.left = True
                for i, e in enumerate(self.events):
                    if e.kind == "gone" and e.robot == st.robot and e.t == v.gone_at:
                        self.events[i] = TopEvent(e.t, *self._gone(v))
            if st.alive:
                live.append((v, prev, st))
            v.status = st
        for v, prev, st in live:
            self._diff_blacklist(v, prev, st, now)
            self._diff_running(v, prev, st, now)

    def _gone(self, v: RobotView) -> tuple[str, str, str]:
        """The event of a robot no longer alive: left, or gone (a crash, a cut link)."""
        n = v.gone_programs
        if v.left:
            return "left", v.name, f"{v.name} left (its node stopped" + (
                f" and handed {n} program(s) back to their origins)" if n else ")")
        return "gone", v.name, (f"{v.name} gone (liveliness lost; last report {(v.gone_at or v.last_heard) - v.last_heard:.1f} s "
                                f"before)" + (f", {n} program(s) were running there" if n else ""))

    def _diff_blacklist(self, v: RobotView, prev: RobotStatus, st: RobotStatus, now: float) -> None:
        after = set(st.blacklisted)
        before = set(prev.blacklisted) if prev is not st else after
        for r in sorted(after - before):
            gone = self.robots.get(r)
            since = f" ({now - gone.last_heard:.1f} s after its last report)" if gone else ""
            self._event(now, "wrote_off", v.name, f"{v.name} wrote {r} off{since}")
        for r in sorted(before - after):
            self._event(now, "cleared", v.name, f"{v.name} uses {r} again")

    def _diff_running(self, v: RobotView, prev: RobotStatus, st: RobotStatus, now: float) -> None:
        have = Counter((p.program, p.origin) for p in st.running)
        old = {k: list(ts) for k, ts in v.running.items()}
        finished = max(0, st.finished_total - (prev.finished_total if prev is not st else st.finished_total))
        new_running: dict[tuple[str, str], list[float]] = {}
        ended: list[tuple[tuple[str, str], float]] = []
        for key, ts in old.items():  # the oldest copies are the ones that ended
            gone_n = len(ts) - have.get(key, 0)
            if gone_n > 0:
                ended.extend((key, t) for t in sorted(ts)[:gone_n])
        for key, n in have.items():
            keep = sorted(old.get(key, []))[-n:]  # n >= 1 here
            for _ in range(n - len(keep)):
                keep.append(now)
                self._started(v.name, key, now)
            new_running[key] = keep
        for key, t0 in sorted(ended, key=lambda e: e[1]):
            what = "finished" if finished > 0 else "stopped"
            finished -= 1
            self._event(now, what, v.name, f"{key[0]} from {key[1]} {what} on {v.name} after {now - t0:.1f} s")
        v.running = new_running

    def _started(self, robot: str, key: tuple[str, str], now: float) -> None:
        waiting = self._displaced.get(key)
        if waiting:
            src, when = waiting.pop(0)
            if not waiting:
                del self._displaced[key]
            src_left = src in self.robots and self.robots[src].left
            self._event(now, "moved", robot, f"{key[0]} from {key[1]} moved {src} -> {robot}, running again "
                        f"{now - when:.1f} s after {src} " + ("left" if src_left else "was lost"))
        else:
            self._event(now, "started", robot, f"{key[0]} from {key[1]} started on {robot}")

    def in_flight(self, origin: str) -> int:
        """Programs of ``origin`` running anywhere on the team now."""
        return sum(1 for v in self.robots.values() if v.alive for p in v.status.running if p.origin == origin)


# ====================================================================== drawing
_EVENT_STYLE = {"joined": "green", "back": "green", "left": "yellow", "gone": "bold red", "wrote_off": "red",
                "cleared": "green", "started": "cyan", "finished": "white", "stopped": "yellow", "moved": "bold magenta"}


def _bar(frac: float, width: int = 10) -> str:
    frac = max(0.0, min(1.0, frac))
    full = int(round(frac * width))
    return "█" * full + "░" * (width - full)


def render(model: TopModel, now: float, *, events: int = 12, interval: float | None = None) -> Group:
    t = Table(title=f"team {model.team}: {len(model.alive())} of {len(model.robots)} robots alive",
              title_justify="left", expand=False, pad_edge=False)
    for name, right in (("robot", False), ("state", False), ("cores", True), ("speed", True), ("CPU", False),
                        ("run q", True), ("running", True), ("in flight", True), ("programs", False),
                        ("mem free", True), ("sees", True), ("blacklists", False)):
        t.add_column(name, justify="right" if right else "left", no_wrap=name != "programs")
    for name in sorted(model.robots):
        v = model.robots[name]
        st = v.status
        if v.alive:
            age = now - v.last_heard
            state = Text("alive" if age < 3 else f"silent {age:.0f} s", style="green" if age < 3 else "yellow")
            style = ""
        else:
            state = Text(f"{'left' if v.left else 'gone'} {now - (v.gone_at or now):.1f} s ago "
                         f"(heard {now - v.last_heard:.1f} s ago)")
            style = "grey50"
        cpu = st.cpu_busy / st.cores if st.cores else 0.0
        progs = Counter(p.program for p in st.running) if v.alive else Counter()
        listed = ", ".join(f"{p}x{n}" if n > 1 else p for p, n in progs.most_common(4))
        t.add_row(name, state, str(st.cores or "-"), f"{st.speed:g}" if st.speed else "-",
                  f"{_bar(cpu)} {100 * cpu:3.0f}%", f"{st.runnable:.1f}", str(st.ramps_running if v.alive else 0),
                  str(model.in_flight(name)), listed, f"{st.mem_free / 2**30:.1f} GiB" if st.mem_free else "-",
                  "-" if st.sees is None else str(st.sees), ", ".join(st.blacklisted), style=style)
    lines = Text()
    start = model.started_at or now
    for e in list(model.events)[-events:]:
        lines.append(f"{e.t - start:8.1f} s  ", style="grey50")
        lines.append(e.text + "\n", style=_EVENT_STYLE.get(e.kind, ""))
    footer = f"refresh every {interval:g} s; Ctrl-C quits" if interval else ""
    return Group(t, Panel(lines or Text("no events yet", style="grey50"), title="recent events",
                          title_align="left", subtitle=footer, subtitle_align="right"))


__all__ = ["TopModel", "TopEvent", "RobotView", "render"]
