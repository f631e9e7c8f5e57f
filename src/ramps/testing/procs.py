"""The processes a ``LocalTeam`` starts: killing a process group, and
finding the live processes tagged with a team in their environment."""

from __future__ import annotations

import os
import signal
import subprocess
from typing import Any

import psutil

__all__ = ["describe", "killpg", "tagged_processes"]


def killpg(p: subprocess.Popen[Any]) -> None:
    try:
        os.killpg(p.pid, signal.SIGKILL)  # the process and everything it started (a node: its workers)
    except (ProcessLookupError, PermissionError):
        pass


def tagged_processes(tag: str, value: str) -> list[psutil.Process]:
    """Live processes (not zombies, not this one) whose environment has ``tag=value``."""
    found = []
    me = os.getpid()
    for p in psutil.process_iter(["pid"]):
        if p.pid == me:
            continue
        try:
            if p.status() == psutil.STATUS_ZOMBIE:
                continue
            if p.environ().get(tag) == value:
                found.append(p)
        except (psutil.NoSuchProcess, psutil.AccessDenied, psutil.ZombieProcess, OSError):
            continue
    return found


def describe(procs: list[psutil.Process]) -> str:
    out = []
    for p in procs:
        try:
            out.append(f"{p.pid}: {' '.join(p.cmdline())}")
        except psutil.Error:
            out.append(f"{p.pid}: ?")
    return "; ".join(out)
