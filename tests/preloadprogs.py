"""Programs for tests/test_forkserver_preload.py (tests/ is on the workers'
PYTHONPATH): what a worker has imported before its first call."""

from __future__ import annotations

import sys

import ramps


def modules(names: list[str]) -> dict[str, bool]:
    """Which of ``names`` this worker had imported when the call came."""
    return {n: n in sys.modules for n in names}


@ramps.program(preload=("preloadprogs_lazy",))
def lazy() -> str:
    import preloadprogs_lazy  # only here: callers that check arguments do not import it

    return preloadprogs_lazy.WHAT


@ramps.program(preload=("preloadprogs_no_such_module",))
def missing() -> str:
    import preloadprogs_no_such_module  # noqa: F401

    return "unreachable"
