"""A node driver's seams to its robot: what it uses of its worker pool and load sampler.

How this works: ``NodeRuntime`` (``ramps.runtime.node``) is given factories
of a worker pool and a load sampler; ``WorkerPoolLike`` and ``SamplerLike``
are what it and its parts use of them, met by ``WorkerPool``/``LoadSampler``
(``ramps.runtime.workers``, ``ramps.runtime.measure``) and by the in-memory
ones of ``ramps.testing.memory``. A running program is known by its ``Key``.
"""

from __future__ import annotations

from typing import Any, Protocol

#: a running program: (program id, attempt)
Key = tuple[str, int]


class WorkerPoolLike(Protocol):
    """What the driver uses of its worker pool (``ramps.runtime.workers.WorkerPool``)."""

    def start(self) -> None: ...

    def stop(self) -> None: ...

    def run(self, key: Key, program: str, args: bytes, resume: bytes | None = None,
            accelerator: dict[str, Any] | None = None) -> None: ...

    def cancel(self, key: Key) -> None: ...

    def busy(self) -> int: ...

    def queued(self) -> int: ...


class SamplerLike(Protocol):
    """What the driver uses of its load sampler (``ramps.runtime.measure.LoadSampler``)."""

    def start(self) -> None: ...

    def stop(self) -> None: ...

    def averages(self) -> tuple[float, float, float]: ...

    def extras(self) -> tuple[list[float], float, int]: ...
