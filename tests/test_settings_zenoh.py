"""What NodeSettings puts into a node's Zenoh configuration."""

from __future__ import annotations

import json

import pytest

from ramps.errors import ConfigError
from ramps.runtime.settings import NodeSettings, load_settings
from ramps.runtime.zenoh_configs import zenoh_config


def shared_memory(s: NodeSettings) -> bool:
    return json.loads(zenoh_config(s).get_json("transport/shared_memory/enabled"))


def shm_threshold(s: NodeSettings) -> int:
    return json.loads(zenoh_config(s).get_json("transport/shared_memory/transport_optimization/message_size_threshold"))


def test_shared_memory_is_off_unless_asked_and_then_only_for_large_messages():
    """Off, a node maps no teammate's 16 MiB pool (robots emulated on one host
    probe each other with 16 KB messages); on, only messages of 64 KB or more
    go through it, unless the operator's raw Zenoh keys say otherwise."""
    assert NodeSettings(robot="r1").shared_memory is False and shared_memory(NodeSettings(robot="r1")) is False
    on = load_settings(environ={"RAMPS_SHARED_MEMORY": "1"}, default_robot=False)
    assert on.shared_memory is True and shared_memory(on) is True
    assert shm_threshold(on) == 64 * 1024
    assert load_settings(flags={"shared_memory": True}, environ={}, default_robot=False).shared_memory is True
    key = "transport/shared_memory/transport_optimization/message_size_threshold"
    assert shm_threshold(NodeSettings(robot="r1", shared_memory=True, zenoh={key: 8192})) == 8192
    with pytest.raises(ConfigError, match="RAMPS_SHARED_MEMORY"):
        load_settings(environ={"RAMPS_SHARED_MEMORY": "sometimes"}, default_robot=False)
