"""The node gives the memory of a drained burst back (``ramps.runtime.heap``).

The flood test (tests/test_flood_e2e.py) measures the effect on a real node;
these check the rule in milliseconds: trim once enough bytes went through,
never while the backlog still holds messages, at most once per threshold."""

from __future__ import annotations

import sys

import pytest

from ramps.runtime.heap import TRIM_AFTER_BYTES, HeapTrimmer


def test_trims_once_enough_arrived_and_the_backlog_drained():
    calls: list[int] = []
    h = HeapTrimmer(threshold=100, trim=lambda: calls.append(1))
    h.note(60)
    assert not h.maybe_trim() and calls == []  # not enough yet
    h.note(50)
    assert not h.maybe_trim(backlog_bytes=10) and calls == []  # still queued: that memory is in use
    assert h.maybe_trim(backlog_bytes=0) and calls == [1] and h.trims == 1
    assert not h.maybe_trim() and calls == [1]  # the count starts again
    for _ in range(4):
        h.note(30)
    assert h.maybe_trim() and calls == [1, 1]


def test_no_allocator_to_ask_means_nothing_happens():
    h = HeapTrimmer(threshold=1, use_glibc=False)
    h.note(10)
    assert h.trim is None and not h.maybe_trim() and h.trims == 0


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc_trim")
def test_the_real_trim_runs_on_this_machine():
    h = HeapTrimmer()
    assert h.threshold == TRIM_AFTER_BYTES
    h.note(TRIM_AFTER_BYTES)
    assert h.maybe_trim() == (h.trim is not None)
