"""What happened in a run, rebuilt from its trace: the data behind ``ramps report``.

How this works: ``load_run(paths)`` reads any of

- node traces (``ramps node --trace FILE``: JSON lines ``{t, wall, robot,
  what, program_id, other, attempt, detail}``; several robots' files merge
  on their Unix time ``wall``),
- a simulator result (``ramps sim run --json --trace``, or a ``SimResult``:
  its ``trace`` entries, its program records and its faults),

into one list of ``Event`` records (time in seconds from the first event)
and ``build_timeline`` turns them into attempts: where each program ran,
from when (``placed``) to when, and how it ended (delivered, failed with
the detection time and reason, rejected, cancelled because another copy
won, or still running). A new attempt of a program after a failed one is a
re-placement (a move, under weak mobility). Faults come from the simulator
(``fault`` entries: crash, network, freeze, recover); node traces show what
the origin noticed (failures, blacklistings) and, on a host, what it ran
for other origins (``started``, ``finished``, ``stopped``: see
``ramps.runtime.node_trace``), so a host's trace alone shows its
attempts, and with its origins' traces the origin's view wins.

Rules: pure data, no plotting (``ramps.observe.plots`` draws it). Times are
as the trace says; nothing here guesses when a fault really struck.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from pathlib import Path

import msgspec


class ReportError(ValueError):
    """A file that is not a trace ramps can read (message for users)."""


@dataclass(frozen=True)
class Event:
    t: float
    robot: str  # who recorded it (the origin for program decisions)
    what: str
    program_id: str = ""
    other: str = ""  # the host, or the robot concerned
    attempt: int = 0
    detail: str = ""


@dataclass
class Attempt:
    program_id: str
    attempt: int
    host: str
    origin: str
    start: float  # placed
    accepted: float | None = None
    end: float | None = None
    #: delivered | failed | rejected | cancelled | running | error, or from a
    #: host's trace alone: finished (its result was sent; delivery is the origin's)
    outcome: str = "running"
    detail: str = ""
    lane: int = 0  # row within the host's band (for the Gantt)


@dataclass
class Fault:
    t: float
    robot: str
    kind: str  # crash | network | freeze | recover


@dataclass
class Timeline:
    robots: list[str]
    attempts: list[Attempt]
    faults: list[Fault]
    #: (t, origin, host, reason) for every attempt written off
    detections: list[tuple[float, str, str, str]]
    #: (t, origin, host) of every blacklisting
    blacklistings: list[tuple[float, str, str]]
    #: delivered programs per robot that ran them
    distribution: dict[str, int]
    end: float
    source: str = ""
    title: str = ""
    #: program_id -> (t, ok) of its delivery
    deliveries: dict[str, tuple[float, bool]] = field(default_factory=dict)

    def replacements(self) -> list[tuple[Attempt, Attempt]]:
        """(previous attempt, next attempt) for every program placed again."""
        by_pid: dict[str, list[Attempt]] = {}
        for a in self.attempts:
            by_pid.setdefault(a.program_id, []).append(a)
        out: list[tuple[Attempt, Attempt]] = []
        for atts in by_pid.values():
            atts.sort(key=lambda a: (a.attempt, a.start))
            out.extend(zip(atts, atts[1:]))
        return out

    def load(self) -> dict[str, list[tuple[float, int]]]:
        """Running attempts (accepted, not ended) per host as step points (t, count)."""
        out: dict[str, list[tuple[float, int]]] = {}
        for r in self.robots:
            edges = []
            for a in self.attempts:
                if a.host == r and a.accepted is not None:
                    edges.append((a.accepted, 1))
                    edges.append((a.end if a.end is not None else self.end, -1))
            edges.sort(key=lambda e: (e[0], e[1]))
            n, pts = 0, [(0.0, 0)]
            for t, d in edges:
                n += d
                pts.append((t, n))
            pts.append((self.end, n))
            out[r] = pts
        return out


# ====================================================================== loading
def load_run(paths: list[Path], *, window: tuple[float, float] | None = None) -> tuple[list[Event], dict]:
    """Events from one simulator result or from one or more node traces, and
    extra facts (``programs`` records of a simulator run, ``robots``, ``title``).
    ``window``: node traces only, the (from, to) Unix times to keep."""
    if not paths:
        raise ReportError("no trace given")
    texts = []
    for p in paths:
        try:
            texts.append((p, Path(p).read_text()))
        except OSError as exc:
            raise ReportError(f"cannot read {p}: {exc.strerror or exc}") from None
    first = texts[0][1].lstrip()[:1]
    if len(texts) == 1 and first == "{" and _is_json_document(texts[0][1]):
        doc = json.loads(texts[0][1])
        if not (isinstance(doc, dict) and ("what" in doc or "t" in doc)):  # else: a one-line trace
            return _from_document(texts[0][0], doc)
    events: list[Event] = []
    for p, text in texts:
        events.extend(_from_jsonl(p, text))
    if window is not None:
        events = [e for e in events if window[0] <= e.t <= window[1]]
    if not events:
        raise ReportError(f"no trace entries in {', '.join(str(p) for p, _ in texts)} (is it a `ramps node --trace` "
                          "file of a node that ran programs?)")
    t0 = min(e.t for e in events)
    events = sorted((_shift(e, t0) for e in events), key=lambda e: e.t)
    return events, {"title": ", ".join(Path(p).name for p, _ in texts)}


def _is_json_document(text: str) -> bool:
    try:
        json.loads(text)
        return True
    except json.JSONDecodeError:
        return False


def _shift(e: Event, t0: float) -> Event:
    return Event(e.t - t0, e.robot, e.what, e.program_id, e.other, e.attempt, e.detail)


def _from_jsonl(path, text: str) -> list[Event]:
    out = []
    for n, line in enumerate(text.splitlines(), 1):
        if not line.strip():
            continue
        try:
            rec = json.loads(line)
            t = float(rec["wall"] if "wall" in rec else rec["t"])
            out.append(Event(t, str(rec.get("robot", "")), str(rec["what"]), str(rec.get("program_id", "")),
                             str(rec.get("other", "")), int(rec.get("attempt", 0) or 0), str(rec.get("detail", ""))))
        except (json.JSONDecodeError, KeyError, TypeError, ValueError) as exc:
            raise ReportError(f"{path}:{n}: not a ramps trace line ({type(exc).__name__}: {exc})") from None
    return out


def _from_document(path, doc) -> tuple[list[Event], dict]:
    if isinstance(doc, dict) and "trace" in doc and "programs" in doc:
        if not doc["trace"]:
            raise ReportError(f"{path} is a simulator result without a trace: run `ramps sim run --json --trace`")
        events = []
        for e in doc["trace"]:
            t, robot, what, pid, other, attempt, detail = e
            events.append(Event(float(t), robot, what, pid, other, int(attempt), detail))
        events.sort(key=lambda e: e.t)
        return events, {"programs": doc["programs"], "robots": doc.get("robots", []),
                        "title": f"simulator: {doc.get('scenario', '')}, policy {doc.get('policy', '')}, "
                                 f"seed {doc.get('seed', '')}"}
    raise ReportError(f"{path}: not a trace (expected `ramps node --trace` JSON lines or `ramps sim run --json "
                      "--trace` output); experiment results are drawn by `ramps report` too, see --help")


# ====================================================================== the timeline
def build_timeline(events: list[Event], extra: dict | None = None) -> Timeline:
    extra = extra or {}
    attempts: dict[tuple[str, int], Attempt] = {}
    faults: list[Fault] = []
    detections: list[tuple[float, str, str, str]] = []
    blacklistings: list[tuple[float, str, str]] = []
    deliveries: dict[str, tuple[float, bool]] = {}
    robots: list[str] = list(extra.get("robots") or [])

    def seen(r: str) -> None:
        if r and r != "*" and r not in robots:
            robots.append(r)

    end = max((e.t for e in events), default=0.0)
    for e in events:
        key = (e.program_id, e.attempt)
        if e.what == "fault":
            faults.append(Fault(e.t, e.robot, e.detail))
            seen(e.robot)
        elif e.what == "placed":
            seen(e.robot)
            seen(e.other)
            attempts[key] = Attempt(e.program_id, e.attempt, e.other, e.robot, e.t)
        elif e.what == "accepted" and key in attempts:
            attempts[key].accepted = e.t
        elif e.what in ("failed", "rejected") and key in attempts:
            a = attempts[key]
            if a.end is None:
                a.end, a.outcome, a.detail = e.t, e.what, e.detail
            if e.what == "failed":
                detections.append((e.t, e.robot, e.other, e.detail))
        elif e.what == "started":  # a host's trace: robot = the host, other = the origin
            seen(e.robot)
            seen(e.other)
            if key not in attempts:  # else the origin's trace placed it
                attempts[key] = Attempt(e.program_id, e.attempt, e.robot, e.other, e.t, accepted=e.t)
        elif e.what in ("finished", "stopped") and key in attempts:
            a = attempts[key]
            if a.end is None and a.host == e.robot:
                a.end, a.detail = e.t, e.detail
                a.outcome = "cancelled" if e.what == "stopped" else "error" if e.detail else "finished"
        elif e.what == "blacklisted":
            blacklistings.append((e.t, e.robot, e.other))
        elif e.what == "delivered":  # node traces: other = host, attempt = attempts, detail = error kind
            _deliver(attempts, e.program_id, e.other, e.t, ok=not e.detail)
            deliveries[e.program_id] = (e.t, not e.detail)
    for rec in extra.get("programs") or []:  # simulator: deliveries come as program records
        if rec.get("delivered_at") is not None:
            _deliver(attempts, rec["program_id"], rec.get("host") or "", float(rec["delivered_at"]),
                     ok=bool(rec.get("ok")))
            deliveries[rec["program_id"]] = (float(rec["delivered_at"]), bool(rec.get("ok")))
            end = max(end, float(rec["delivered_at"]))
    if not extra.get("robots"):  # node traces: r1, r2, ..., r10 in natural order
        robots.sort(key=lambda r: [int(x) if x.isdigit() else x for x in re.split(r"(\d+)", r)])
    distribution = {r: 0 for r in robots}
    for a in attempts.values():
        if a.outcome == "delivered" and deliveries.get(a.program_id, (0, False))[1]:
            distribution[a.host] = distribution.get(a.host, 0) + 1
    tl = Timeline(robots=robots, attempts=sorted(attempts.values(), key=lambda a: (a.start, a.program_id)),
                  faults=faults, detections=detections, blacklistings=blacklistings, distribution=distribution,
                  end=end, title=extra.get("title", ""), deliveries=deliveries)
    _assign_lanes(tl)
    return tl


def _deliver(attempts: dict[tuple[str, int], Attempt], pid: str, host: str, t: float, *, ok: bool) -> None:
    """The program's delivery ends its winning attempt (the latest on
    ``host``) as delivered and every other open attempt as cancelled."""
    mine = [a for (p, _), a in attempts.items() if p == pid]
    on_host = [a for a in mine if a.host == host]
    # the live attempt there; else one written off while its host still published (a
    # suspected host keeps its copy wanted, and that copy may be the one that delivers)
    winner = max((a for a in on_host if a.outcome in ("running", "delivered")), key=lambda a: a.attempt,
                 default=max(on_host, key=lambda a: a.attempt, default=None))
    for a in mine:
        if a is winner:
            a.end, a.outcome = t, "delivered" if ok else "error"
        elif a.end is None:
            a.end, a.outcome = t, "cancelled"


def _assign_lanes(tl: Timeline) -> None:
    """Pack each host's attempts into rows so that bars do not overlap."""
    for r in tl.robots:
        lanes: list[float] = []  # end time of the last bar in each lane
        for a in sorted((a for a in tl.attempts if a.host == r), key=lambda a: a.start):
            end = a.end if a.end is not None else tl.end
            for i, free_at in enumerate(lanes):
                if free_at <= a.start + 1e-9:
                    a.lane, lanes[i] = i, end
                    break
            else:
                a.lane = len(lanes)
                lanes.append(end)


def sim_result_events(res) -> tuple[list[Event], dict]:
    """Events and extras straight from a ``SimResult`` object (no file)."""
    doc = json.loads(msgspec.json.encode(res))
    return _from_document("<simulation>", doc)


__all__ = ["Event", "Attempt", "Fault", "Timeline", "ReportError", "load_run", "build_timeline", "sim_result_events"]
