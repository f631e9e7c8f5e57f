"""The origin's timers: one heap of every program's pending timer.

How this works: a program has at most one timer at a time: when it is due
(``AutonomousProgram.deadline``, absolute) and which event it fires
(``AutonomousProgram.timer``: connect timeout, heartbeat timeout, back-off
done). Setting one pushes (when, sequence, program id) on the heap; an
entry whose program has set another timer since, ended or been forgotten is
stale and dropped when it reaches the top. The sequence keeps timers due at
the same moment in the order they were set.

Rules: no clock (``now`` comes in); programs are looked up in the origin's
table, passed to each call.
"""

from __future__ import annotations

import heapq
from collections.abc import Iterator, Mapping

from ramps.core.program import FINAL, AutonomousProgram, Event


class Timers:
    """The pending timers of one origin's programs."""

    def __init__(self) -> None:
        self._heap: list[tuple[float, int, str]] = []
        self._seq = 0

    def set(self, ap: AutonomousProgram, when: float, kind: Event) -> None:
        """``ap``'s timer is now ``kind`` at ``when`` (any earlier one is void)."""
        ap.deadline = when
        ap.timer = kind
        self._seq += 1
        heapq.heappush(self._heap, (when, self._seq, ap.program_id))

    def first(self, programs: Mapping[str, AutonomousProgram]) -> float | None:
        """When the earliest pending timer is due (stale entries dropped)."""
        heap = self._heap
        while heap:
            top = heap[0]
            ap = programs.get(top[2])
            if ap is not None and ap.deadline == top[0]:
                return top[0]
            heapq.heappop(heap)  # stale entry
        return None

    def due(self, now: float, programs: Mapping[str, AutonomousProgram]) -> Iterator[AutonomousProgram]:
        """The live programs whose timer is due at ``now``, earliest first,
        each with its timer taken off (``deadline`` None; ``timer`` still
        names it). A timer set meanwhile that is due by ``now`` comes in turn."""
        while self._heap and self._heap[0][0] <= now:
            when, _, pid = heapq.heappop(self._heap)
            ap = programs.get(pid)
            if ap is None or ap.deadline != when or ap.state in FINAL:
                continue
            ap.deadline = None
            yield ap
