"""Sites and routers in the settings: Zenoh's mode, raw Zenoh settings, endpoints, the router's config."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from typer.testing import CliRunner

from ramps.cli import app
from ramps.errors import ConfigError
from ramps.runtime.credentials import Credentials
from ramps.runtime.settings import (
    NodeSettings,
    check_endpoint,
    flatten_zenoh,
    load_settings,
    parse_zenoh_overrides,
)
from ramps.runtime.zenoh_configs import router_config, router_listen, zenoh_config


def get(c, key: str):
    return json.loads(c.get_json(key))


def settings(**flags) -> NodeSettings:
    return load_settings(flags=flags, environ={}, default_robot=False)


# ---------------------------------------------------------------- mode
def test_peer_is_the_default_and_client_mode_flows_from_flag_env_and_file(tmp_path: Path):
    assert settings().mode == "peer" and get(zenoh_config(settings()), "mode") == "peer"
    flag = settings(mode="client", connect=["tcp/10.0.0.1:7447"])
    assert get(zenoh_config(flag), "mode") == "client"
    env = load_settings(environ={"RAMPS_MODE": "client", "RAMPS_CONNECT": "tcp/10.0.0.1:7447"}, default_robot=False)
    assert env.mode == "client"
    cfg = tmp_path / "node.toml"
    cfg.write_text('mode = "client"\nconnect = ["tcp/10.0.0.1:7447"]\n')
    assert load_settings(config_file=cfg, environ={}, default_robot=False).mode == "client"
    # a flag beats the file
    assert load_settings(config_file=cfg, flags={"mode": "peer"}, environ={}, default_robot=False).mode == "peer"


def test_a_client_never_listens():
    c = zenoh_config(settings(mode="client", connect=["tcp/10.0.0.1:7447"]))
    assert get(c, "listen/endpoints") == [] and get(c, "connect/endpoints") == ["tcp/10.0.0.1:7447"]


@pytest.mark.parametrize("flags, words", [
    ({"mode": "router"}, "ramps router"),
    ({"mode": "cliente"}, "peer or client"),
    ({"mode": "client", "connect": ["tcp/10.0.0.1:7447"], "listen": ["tcp/0.0.0.0:7447"]}, "does not listen"),
    ({"mode": "client", "multicast": False}, "needs a router"),
])
def test_bad_modes_are_clear(flags, words):
    with pytest.raises(ConfigError, match=words):
        settings(**flags)


# ---------------------------------------------------------------- endpoints
@pytest.mark.parametrize("endpoint", ["tcp/127.0.0.1:7447", "tls/[::1]:7447", "udp/0.0.0.0:0",
                                      "tcp/robot1.local:7447#iface=eth0", "quic/10.0.0.1:7447",
                                      "unixsock-stream/tmp/ramps.sock"])
def test_good_endpoints(endpoint):
    check_endpoint(endpoint)


@pytest.mark.parametrize("endpoint, words", [
    ("127.0.0.1:7447", "PROTOCOL/HOST:PORT"),
    ("tpc/127.0.0.1:7447", "unknown protocol 'tpc'"),
    ("tcp/127.0.0.1", "needs a host and a port"),
    ("tcp/:7447", "needs a host and a port"),
    ("tcp/127.0.0.1:70000", "port 0-65535"),
])
def test_bad_endpoints_say_what_is_wrong(endpoint, words):
    with pytest.raises(ValueError, match=words):
        check_endpoint(endpoint)
    with pytest.raises(ConfigError, match=words):
        settings(connect=[endpoint])


# ---------------------------------------------------------------- raw Zenoh settings
def test_zenoh_table_is_applied_last_leaf_by_leaf(tmp_path: Path):
    cfg = tmp_path / "node.toml"
    cfg.write_text('[zenoh.transport.link.tx]\nbatch_size = 8192\n[zenoh]\n"scouting/gossip/enabled" = false\n')
    s = load_settings(config_file=cfg, environ={}, default_robot=False)
    c = zenoh_config(s)
    assert get(c, "transport/link/tx/batch_size") == 8192 and get(c, "scouting/gossip/enabled") is False
    assert get(c, "transport/link/tx/lease") == s.lease_ms  # a leaf, not the whole subtree, was replaced
    # --zenoh adds to the file's table and wins over it
    s2 = load_settings(config_file=cfg, flags={"zenoh": parse_zenoh_overrides(
        ["transport/link/tx/batch_size=4096", "transport/link/tx/queue/batching/time_limit=2"])},
        environ={}, default_robot=False)
    c2 = zenoh_config(s2)
    assert get(c2, "transport/link/tx/batch_size") == 4096 and get(c2, "scouting/gossip/enabled") is False
    assert get(c2, "transport/link/tx/queue/batching/time_limit") == 2


def test_flatten_and_parse():
    assert flatten_zenoh({"a": {"b": {"c": 1}, "d/e": [1, 2]}, "/f/": "x"}) == {"a/b/c": 1, "a/d/e": [1, 2], "f": "x"}
    assert parse_zenoh_overrides(["x/y=3", "s=greater-zid", "q=\"quoted\"", "l=[1,2]"]) == {
        "x/y": 3, "s": "greater-zid", "q": "quoted", "l": [1, 2]}
    with pytest.raises(ConfigError, match="KEY=VALUE"):
        parse_zenoh_overrides(["batch_size"])


@pytest.mark.parametrize("table, words", [
    ({"mode": "router"}, "use --mode"),
    ({"listen": {"endpoints": ["tcp/0.0.0.0:1"]}}, "use --listen"),
    ({"transport/link/tx/batch_sizze": 3}, "Zenoh refused it"),
    ({"transport/link/tx/batch_size": "big"}, "Zenoh refused it"),
])
def test_refused_zenoh_settings(table, words):
    with pytest.raises(ConfigError, match=words):
        settings(zenoh=table)


def test_a_secured_team_refuses_zenoh_settings_that_touch_tls_or_access_control():
    for table in ({"access_control": {"enabled": False}}, {"transport/link/tls/enable_mtls": False},
                  {"transport": {"link": {"protocols": ["tcp", "tls"]}}}):
        with pytest.raises(ConfigError, match="refused on a secured team"):
            settings(zenoh=table, secure=True, credentials="/nowhere")
    settings(zenoh={"access_control": {"enabled": False}})  # not secured: the operator's call


# ---------------------------------------------------------------- the router
def test_router_config_from_the_same_settings():
    s = settings(connect=["tcp/10.0.2.1:7447"], lease_ms=1500, multicast=False,
                 zenoh={"transport/link/tx/batch_size": 8192})
    c = router_config(s)
    assert get(c, "mode") == "router"
    assert get(c, "listen/endpoints") == ["tcp/0.0.0.0:7447"]  # the node default becomes the router's port
    assert get(c, "connect/endpoints") == ["tcp/10.0.2.1:7447"]
    assert get(c, "transport/link/tx/lease") == 1500 and get(c, "scouting/multicast/enabled") is False
    assert get(c, "transport/link/tx/batch_size") == 8192
    assert router_listen(settings(listen=["tcp/10.0.1.250:7000"])) == ["tcp/10.0.1.250:7000"]
    # the testbed's routers share one host: large messages must cross their (slowed) link, not shared memory
    assert get(router_config(settings(shared_memory=False)), "transport/shared_memory/enabled") is False


def test_a_secured_router_holds_team_tls_and_the_acl(tmp_path: Path):
    creds = Credentials(ca=tmp_path / "ca.pem", cert=tmp_path / "cert.pem", key=tmp_path / "key.pem",
                        robot="router-a", team="wh", not_after=None)  # type: ignore[arg-type]
    s = settings(team="wh", secure=True, credentials=str(tmp_path), connect=["tls/10.0.2.1:7447"])
    c = router_config(s, credentials=creds)
    assert get(c, "listen/endpoints") == ["tls/0.0.0.0:7447"]
    assert get(c, "transport/link/protocols") == ["tls"]
    tls = get(c, "transport/link/tls")
    assert tls["enable_mtls"] is True and tls["connect_certificate"] == str(tmp_path / "cert.pem")
    acl = get(c, "access_control")
    assert acl["enabled"] is True and acl["default_permission"] == "deny"
    assert acl["rules"][0]["key_exprs"] == ["ramps/wh/**"]
    with pytest.raises(ValueError, match="credentials"):
        router_config(s)


# ---------------------------------------------------------------- the CLI
def test_router_cli_help_and_clear_errors():
    r = CliRunner().invoke(app, ["router", "--help"], env={"COLUMNS": "120"})
    assert r.exit_code == 0 and "client mode" in r.output and "peer mode" in r.output
    r = CliRunner().invoke(app, ["router", "--connect", "tcp/nowhere", "--no-multicast"])
    assert r.exit_code == 2 and "needs a host and a port" in r.output
    r = CliRunner().invoke(app, ["router", "--zenoh", "mode=peer"])
    assert r.exit_code == 2 and "ramps's own" in r.output
    r = CliRunner().invoke(app, ["node", "--help"], env={"COLUMNS": "120"})
    assert "--mode" in r.output and "client" in r.output


def test_an_application_chooses_its_mode_and_a_client_without_a_router_is_told_at_once():
    import ramps
    from ramps.errors import ConfigError

    with pytest.raises(ConfigError, match="client mode needs a router"):
        ramps.connect(team="t", mode="client", multicast=False, timeout=0.1)
    with pytest.raises(ConfigError, match="mode must be peer or client, got 'router'"):
        ramps.connect(team="t", mode="router", timeout=0.1)
