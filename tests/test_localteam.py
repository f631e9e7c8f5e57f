"""Free loopback ports for nodes started side by side (ramps.runtime.localteam)."""

from __future__ import annotations

import random
import socket

import pytest

from ramps.runtime import localteam
from ramps.runtime.localteam import free_port


def test_ports_are_free_distinct_and_below_the_ephemeral_range():
    lo, _ = localteam._ephemeral_range()
    ports = [free_port() for _ in range(50)]
    assert len(set(ports)) == 50
    assert all(10000 <= p < lo for p in ports) or lo - 10000 < 1000
    for p in ports:
        with socket.socket() as s:
            s.bind(("127.0.0.1", p))  # nothing listens there


def test_a_port_in_use_is_skipped(monkeypatch):
    lo, _ = localteam._ephemeral_range()
    if lo - 10000 < 1000:
        pytest.skip("no room below the ephemeral range here: the kernel picks")
    first = random.Random(7).randrange(10000, lo)
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", first))
        busy.listen()
        monkeypatch.setattr(localteam, "_PICK", random.Random(7))
        monkeypatch.setattr(localteam, "_GIVEN", set())
        assert free_port() != first
