"""A robot's accelerators on a real node: found, measured, handed to programs.

How this works: the node's ``accelerators`` setting lists what this robot
advertises (``ramps.core.accelerators``): ``auto`` (the default) asks NVIDIA's
management library (NVML, the ``nvidia-ml-py`` package, imported only here)
for the robot's GPUs and advertises them as ``cuda``, one slot each at
speed 1; ``KIND[:COUNT[:SPEED]]`` declares one kind (``cuda:1:20`` pins a
speed, ``npu:2``); ``none`` advertises nothing. A kind marked
``emulated`` (``cuda:1:20:emulated``, the testbed's) is a set of slot locks
instead of a device: programs given it hold a slot while they wait out
their work (``Grant.emulate``), so a robot without a GPU can stand in for one.

While programs run, ``AcceleratorProbe.measure`` reads each NVIDIA device's
memory and utilisation for the load reports. A program started on an
accelerator gets a ``Grant`` (``ramps.accelerator()`` in the program): the
kind, the device to use (``cuda:0``; the least used of the robot's devices)
and whether it is emulated.
"""

from __future__ import annotations

import fcntl
import os
import random
import shutil
import tempfile
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ramps.core.accelerators import Accelerator, parse_accelerator


@dataclass(frozen=True)
class Grant:
    """The accelerator a running program was given (``ramps.accelerator()``)."""

    kind: str
    #: what to hand the program's library: ``cuda:0`` for a GPU
    device: str
    index: int = 0
    #: work units per second of one slot (the robot's advertised speed)
    speed: float = 1.0
    #: an emulated accelerator: its slot locks live in ``slots_dir``
    emulated: bool = False
    slots_dir: str = ""
    count: int = 1

    def as_wire(self) -> dict[str, Any]:
        return {"kind": self.kind, "device": self.device, "index": self.index, "speed": self.speed,
                "emulated": self.emulated, "slots_dir": self.slots_dir, "count": self.count}

    @classmethod
    def from_wire(cls, data: dict[str, Any]) -> "Grant":
        return cls(**{k: data[k] for k in ("kind", "device", "index", "speed", "emulated", "slots_dir", "count")
                      if k in data})

    def emulate(self, work: float) -> float:
        """Do ``work`` units on an emulated accelerator: take one of its slots
        (a lock shared by the robot's programs, waited for while all are
        taken) and hold it until ``work / speed`` seconds have passed by the
        clock, as a device computes while its program's process waits: a
        robot whose CPU quota throttles the process still gets the slot's
        speed. Programs that outnumber the slots take turns (a node starts at
        most one per slot). Returns the wall seconds taken, a wait for a slot
        included."""
        if not self.emulated:
            raise RuntimeError(f"accelerator {self.kind!r} ({self.device}) is a real device, not an emulated one")
        need = max(0.0, work) / self.speed
        start = time.monotonic()
        fds = [os.open(os.path.join(self.slots_dir, f"slot-{i}"), os.O_RDWR | os.O_CREAT, 0o666)
               for i in range(self.count)]
        try:
            fd = _take_a_slot(fds, random.Random())
            try:
                done = time.monotonic() + need
                while (left := done - time.monotonic()) > 0:
                    time.sleep(left)
            finally:
                fcntl.flock(fd, fcntl.LOCK_UN)
        finally:
            for fd in fds:
                os.close(fd)
        return time.monotonic() - start


def _take_a_slot(fds: list[int], rng: random.Random) -> int:
    """Lock a free slot if there is one, else wait for one chosen at random."""
    for fd in rng.sample(fds, len(fds)):
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            return fd
        except BlockingIOError:
            continue
    fd = rng.choice(fds)
    fcntl.flock(fd, fcntl.LOCK_EX)
    return fd


@dataclass(frozen=True)
class Declared:
    """One entry of the ``accelerators`` setting, resolved."""

    accelerator: Accelerator
    emulated: bool = False
    #: NVIDIA device indices behind it (NVML), empty for declared or emulated ones
    devices: tuple[int, ...] = ()


def check_setting(entries: list[str]) -> None:
    """Check the ``accelerators`` setting's entries: ValueError naming a bad one."""
    for text in entries:
        if text not in ("auto", "none"):
            try:
                _parse(text)
            except ValueError as exc:
                raise ValueError(f"accelerators: {exc} (or 'auto', 'none'; add ':emulated' for an emulated "
                                 f"one)") from None


def _parse(text: str) -> tuple[Accelerator, bool]:
    emulated = text.endswith(":emulated")
    return parse_accelerator(text[: -len(":emulated")] if emulated else text), emulated


def resolve(entries: list[str]) -> list[Declared]:
    """What this robot advertises for the ``accelerators`` setting: ``auto``
    finds NVIDIA GPUs (none where NVML or a GPU is missing); an explicit
    ``cuda`` entry is matched with the GPUs found, so its devices are real."""
    if "none" in entries:
        return []
    found = nvidia_devices() if ("auto" in entries or any(e.split(":")[0] == "cuda" for e in entries)) else []
    out: list[Declared] = []
    for text in entries:
        if text == "auto":
            if found and not any(e.split(":")[0] == "cuda" for e in entries if e != "auto"):
                out.append(Declared(Accelerator(kind="cuda", count=len(found)), devices=tuple(found)))
            continue
        acc, emulated = _parse(text)
        devices = tuple(found[:acc.count]) if acc.kind == "cuda" and not emulated else ()
        out.append(Declared(acc, emulated=emulated, devices=devices))
    return out


def nvidia_devices() -> list[int]:
    """Indices of the NVIDIA GPUs NVML sees (empty without NVML or a GPU)."""
    try:
        import pynvml  # nvidia-ml-py
    except ImportError:
        return []
    try:
        pynvml.nvmlInit()
        return list(range(pynvml.nvmlDeviceGetCount()))
    except Exception:  # no driver, no device: nothing to advertise
        return []


def slot_folder(team: str, robot: str, kind: str) -> Path:
    """Where an emulated accelerator's slot locks live: one folder per team,
    robot and kind, so a node restarted after a crash uses its own again."""
    return Path(tempfile.gettempdir()) / f"ramps-accel-{team}-{robot}-{kind}"


def remove_slot_folders(team: str) -> None:
    """Remove every emulated accelerator's slot folder of ``team`` (a harness
    whose nodes were killed before they could)."""
    for path in Path(tempfile.gettempdir()).glob(f"ramps-accel-{team}-*"):
        shutil.rmtree(path, ignore_errors=True)


class AcceleratorProbe:
    """Hands out devices to programs and measures them for the reports.

    A kind's slots are exclusive: at most ``count`` programs run on it at
    once, each on the least used of its devices, and the others wait in
    order of arrival (``start``) until one ends (``release``), so a GPU holds
    only as many programs' contexts as it has slots. The cost model's
    processor sharing ends a batch at the same time. Called from the node's
    driver thread only."""

    def __init__(self, robot: str, declared: list[Declared], team: str = "") -> None:
        self.declared = {d.accelerator.kind: d for d in declared}
        #: programs on each device index, per kind (the next goes to the least used)
        self._using: dict[str, list[int]] = {d.accelerator.kind: [0] * max(1, len(d.devices) or d.accelerator.count)
                                             for d in declared}
        #: programs holding a slot: key -> (kind, device slot, when it was granted)
        self._held: dict[tuple[str, int], tuple[str, int, float]] = {}
        #: programs waiting for a slot of each kind, in order: (key, how to start it)
        self._waiting: dict[str, deque[tuple[tuple[str, int], Callable[[Grant | None], None]]]] = {
            d.accelerator.kind: deque() for d in declared}
        self._slots: dict[str, str] = {}
        for d in declared:
            if d.emulated:
                path = slot_folder(team, robot, d.accelerator.kind)
                path.mkdir(exist_ok=True)
                self._slots[d.accelerator.kind] = str(path)

    @property
    def accelerators(self) -> list[Accelerator]:
        return [d.accelerator for d in self.declared.values()]

    def start(self, key: tuple[str, int], kind: str, run: Callable[[Grant | None], None]) -> None:
        """Start the program ``key`` on ``kind``: ``run(grant)`` now if a slot
        is free, else when one frees; ``run(None)`` (a CPU) if this robot has
        no such kind."""
        d = self.declared.get(kind)
        if d is None:
            run(None)
        elif sum(self._using[kind]) < d.accelerator.count:
            run(self.grant(key, kind))
        else:
            self._waiting[kind].append((key, run))

    def waiting(self) -> int:
        """Programs waiting for a slot here now."""
        return sum(len(q) for q in self._waiting.values())

    def grant(self, key: tuple[str, int], kind: str) -> Grant | None:
        """A device of ``kind`` for the program ``key`` (None: no such kind here)."""
        d = self.declared.get(kind)
        if d is None:
            return None
        using = self._using[kind]
        slot = min(range(len(using)), key=using.__getitem__)
        using[slot] += 1
        self._held[key] = (kind, slot, time.monotonic())
        index = d.devices[slot] if d.devices else slot
        device = f"{kind}:{index}"
        return Grant(kind=kind, device=device, index=index, speed=d.accelerator.speed, emulated=d.emulated,
                     slots_dir=self._slots.get(kind, ""), count=d.accelerator.count)

    def release(self, key: tuple[str, int]) -> float | None:
        """The program ``key`` ended or was stopped (nothing if it had no
        grant): its slot goes to the program that waited longest. Returns the
        seconds it held its slot (None: it had none), what its work there
        took (``ProgramFinished.slot_s``)."""
        held = self._held.pop(key, None)
        if held is None:
            for queue in self._waiting.values():  # stopped while it waited
                for i, (waiting, _) in enumerate(queue):
                    if waiting == key:
                        del queue[i]
                        return None
            return None
        kind, slot, since = held
        self._using[kind][slot] = max(0, self._using[kind][slot] - 1)
        if self._waiting[kind]:
            nxt, run = self._waiting[kind].popleft()
            run(self.grant(nxt, kind))
        return time.monotonic() - since

    def held(self) -> int:
        """Programs running on an accelerator here now."""
        return len(self._held)

    def measure(self) -> dict[str, tuple[int, int, float | None]]:
        """kind -> (memory total, memory free, utilisation 0..1) of the real
        devices (NVML); emulated and declared kinds are not measured."""
        out: dict[str, tuple[int, int, float | None]] = {}
        for kind, d in self.declared.items():
            if not d.devices:
                continue
            try:
                import pynvml

                total = free = 0
                util = 0.0
                for index in d.devices:
                    handle = pynvml.nvmlDeviceGetHandleByIndex(index)
                    mem = pynvml.nvmlDeviceGetMemoryInfo(handle)
                    total += int(mem.total)
                    free += int(mem.free)
                    util += pynvml.nvmlDeviceGetUtilizationRates(handle).gpu / 100.0
                out[kind] = (total, free, min(1.0, util / len(d.devices)))
            except Exception:  # a device that stops answering is not measured this time
                continue
        return out

    def close(self) -> None:
        for path in self._slots.values():
            for name in os.listdir(path) if os.path.isdir(path) else ():
                try:
                    os.unlink(os.path.join(path, name))
                except OSError:
                    pass
            try:
                os.rmdir(path)
            except OSError:
                pass
