"""What NodeSettings puts into a node's Zenoh configuration."""

from __future__ import annotations

import json

import pytest

from ramps.errors import ConfigError
from ramps.runtime.settings import NodeSettings, load_settings
from ramps.runtime.zenoh_configs import zenoh_config


def shared_memory(s: NodeSettings) -> bool:
    return json.loads(zenoh_config(s).get_json("transport/shared_memory/enabled"))


def test_shared_memory_is_zenoh_s_default_and_can_be_turned_off():
    """The testbed's robots share one host: their large messages must cross the
    emulated network, not Zenoh's shared memory (RAMPS_SHARED_MEMORY=0)."""
    assert shared_memory(NodeSettings(robot="r1")) is True
    off = load_settings(environ={"RAMPS_SHARED_MEMORY": "0"}, default_robot=False)
    assert off.shared_memory is False and shared_memory(off) is False
    assert load_settings(flags={"shared_memory": False}, environ={}, default_robot=False).shared_memory is False
    with pytest.raises(ConfigError, match="RAMPS_SHARED_MEMORY"):
        load_settings(environ={"RAMPS_SHARED_MEMORY": "sometimes"}, default_robot=False)
