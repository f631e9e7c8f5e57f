"""``detect``: a stand-in for a perception network, on a GPU where the robot
offers one (``accelerator="cuda"``) and on one CPU core elsewhere.

How this works: ``reps`` products of two ``size`` x ``size`` float32
matrices with PyTorch (imported when the program runs: the robot needs
``torch``; the node's fork server imports it once, ``preload``). On a GPU
(``ramps.accelerator()`` names the device) the products run there; on a CPU
PyTorch is held to one thread, one core, as the cost model assumes. Its
declared work: about 0.35 CPU seconds per product of 2048 (a reference
core doing about 50 GFLOP/s), and 0.001 s per product on a GPU slot of
speed 1 (an NVIDIA H100 does one in well under a millisecond).
"""

from __future__ import annotations

import time
from typing import Any

from ramps.runtime.registry import program


def _flops(size: int, reps: int) -> float:
    return 2.0 * size ** 3 * reps


@program(work=lambda size=2048, reps=10, **_: 0.35 * reps * (size / 2048) ** 3, payload=40, result=120,
         preload=("torch",), accelerator="cuda",
         accelerator_work=lambda size=2048, reps=10, **_: 0.001 * reps * (size / 2048) ** 3)
def detect(size: int = 2048, reps: int = 10, seed: int = 0) -> dict[str, Any]:
    """``reps`` products of two random ``size`` x ``size`` matrices; returns
    the device, the seconds the products took there and a checksum."""
    if not (1 <= size <= 16384 and 1 <= reps <= 100_000):
        raise ValueError(f"size must be 1..16384 and reps 1..100000, got {size}, {reps}")
    import torch

    import ramps

    grant = ramps.accelerator()
    if grant is None or grant.emulated:
        torch.set_num_threads(1)
        device = torch.device("cpu")
    else:
        device = torch.device(grant.device)
    gen = torch.Generator(device="cpu").manual_seed(seed)
    a = torch.rand(size, size, generator=gen).to(device)
    b = torch.rand(size, size, generator=gen).to(device)
    if device.type == "cuda":
        torch.cuda.synchronize(device)
    start = time.perf_counter()
    c = a
    for _ in range(reps):
        c = torch.tanh(c @ b / size)
    checksum = float(c.sum())  # waits for the device
    seconds = time.perf_counter() - start
    return {"device": str(device), "seconds": round(seconds, 6), "checksum": round(checksum, 3),
            "gflops": round(_flops(size, reps) / seconds / 1e9, 1)}
