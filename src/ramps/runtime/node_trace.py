"""A node's trace file: one JSON line per decision (``--trace``).

How this works: ``NodeTrace`` is a part of the node's driver
(``ramps.runtime.node``); it opens the file at start, writes a line for
each of the core's notes and for what the driver saw (a stall, a
teammate back, a speed measured, with ``--trace-wire`` every message in and
out) and closes it at the end. A write that fails (a full disk) turns the
trace off and the node runs on. Programs this robot hosts for other
origins are traced as it runs them (``hosted``): their origin's notes are
in that origin's trace, so a host's trace alone shows what it ran
(``ramps.observe.timeline``). Lines have the fields of the simulator's
trace (``ramps.sim.engine.TraceEntry``); ``t`` is the clock's monotonic
time (one clock for every process of a host), ``wall`` the Unix time.
"""

from __future__ import annotations

import json
import logging
from typing import TextIO

from ramps.core.events import Send, StartProgram, StopProgram
from ramps.core.messages import ProgramCheckpoint, ProgramResult
from ramps.errors import ConfigError
from ramps.runtime.transport import Clock

log = logging.getLogger("ramps.node")


class NodeTrace:
    """The trace of robot ``robot``'s node, off until ``open``."""

    def __init__(self, robot: str, clock: Clock) -> None:
        self.robot = robot
        self.clock = clock
        self._file: TextIO | None = None
        #: every message in and out is traced too (``--trace-wire``)
        self.wire = False
        #: the origins of the programs this robot hosts for others: (program id, attempt) -> origin
        self._hosted: dict[tuple[str, int], str] = {}

    @property
    def on(self) -> bool:
        """Whether lines are written (a caller skips building a costly detail when not)."""
        return self._file is not None

    def open(self, path: str, *, wire: bool) -> None:
        """Append to ``path`` from now on; ConfigError if it cannot be written."""
        try:
            self._file = open(path, "a", buffering=1)
        except OSError as exc:
            raise ConfigError(f"cannot write the trace file {path}: {exc.strerror or exc}") from None
        self.wire = wire

    def close(self) -> None:
        if self._file is not None:
            self.wire = False
            self._file.close()
            self._file = None

    def write(self, what: str, program_id: str, other: str, attempt: int, detail: str, *,
              at: float | None = None) -> None:
        """One line: ``what`` happened to ``program_id`` (attempt ``attempt``)
        with robot ``other``, at ``at`` (default: now) on the clock's
        monotonic time. Nothing when the trace is off."""
        trace = self._file
        if trace is None:  # off, or closed meanwhile (a write failed, or the node was torn down)
            return
        rec = {"t": round(self.clock.monotonic() if at is None else at, 6), "wall": round(self.clock.time(), 6),
               "robot": self.robot, "what": what, "program_id": program_id, "other": other, "attempt": attempt,
               "detail": detail}
        try:
            trace.write(json.dumps(rec) + "\n")
        except OSError as exc:  # a full disk must not stop the node
            log.warning("node %s: trace file write failed, trace off: %s", self.robot, exc)
            self._file = None
            self.wire = False

    def hosted(self, a: StartProgram | StopProgram | Send, *, closing: bool) -> None:
        """The host's side of the trace, for programs of other origins (this
        robot's own are in its origin notes), ``other`` the origin:
        ``started`` (detail: the program, and the progress it resumes from),
        ``checkpointed`` (detail: its progress then, if it reported any),
        ``finished`` (its result is sent; detail: empty if it returned, else
        its error's last line) or ``stopped`` (no longer wanted: withdrawn,
        another copy won, its origin gone; "handed back" when this node
        leaves: ``closing``)."""
        hosted = self._hosted
        if isinstance(a, StartProgram):
            if a.origin != self.robot:
                hosted[(a.program_id, a.attempt)] = a.origin
                self.write("started", a.program_id, a.origin, a.attempt, a.program + (
                    f" resumed from {a.resume_fraction:.2f}" if a.resume is not None else ""))
        elif isinstance(a, StopProgram):
            origin = hosted.pop((a.program_id, a.attempt), None)
            if origin is not None:
                self.write("stopped", a.program_id, origin, a.attempt, "handed back" if closing else "")
        elif isinstance(a.msg, ProgramResult):  # the first send only: resends find it gone
            origin = hosted.pop((a.msg.program_id, a.msg.attempt), None)
            if origin is not None:
                error = a.msg.error.strip().splitlines()
                self.write("finished", a.msg.program_id, origin, a.msg.attempt,
                           "" if a.msg.ok else (error[-1][:200] if error else "error"))
        elif isinstance(a.msg, ProgramCheckpoint) and (a.msg.program_id, a.msg.attempt) in hosted:
            self.write("checkpointed", a.msg.program_id, a.to, a.msg.attempt,
                       "" if a.msg.fraction is None else f"{a.msg.fraction:.2f}")
