"""The node's niceness and its workers': the node above its programs, so
heartbeats and load reports keep their timing on a busy robot."""

from __future__ import annotations

import logging
import os

log = logging.getLogger("ramps.node")


def prioritize(nice: int) -> bool:
    """Give this process niceness ``nice``: every thread it has, and those it
    starts later (they inherit it). Call it before the node starts. Below 0
    needs root (or CAP_SYS_NICE): without, one log line, and it stays as it
    is. True if the process runs at ``nice`` now."""
    try:
        current = os.getpriority(os.PRIO_PROCESS, 0)
        tids = [int(t) for t in os.listdir("/proc/self/task")] if os.path.isdir("/proc/self/task") else [0]
    except (OSError, AttributeError):
        return False
    if current == nice:
        return True
    for tid in tids:
        try:
            os.setpriority(os.PRIO_PROCESS, tid, nice)
        except ProcessLookupError:
            continue  # that thread ended meanwhile
        except PermissionError:
            log.warning("node: cannot give itself niceness %d (needs root or CAP_SYS_NICE); it stays at %d",
                        nice, current)
            return False
    return True


def worker_increment(worker_nice: int) -> int:
    """The niceness a worker adds to this thread's (it inherits the node's,
    ``prioritize``, then adds this) so that it runs at ``worker_nice``."""
    try:
        return max(0, worker_nice - os.getpriority(os.PRIO_PROCESS, 0))
    except (OSError, AttributeError):
        return worker_nice
