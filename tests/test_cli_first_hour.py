"""What a new user meets first: ``ramps --version``, a program module that
fails to import, and the port a node really listens on."""

from __future__ import annotations

import signal
import socket

from typer.testing import CliRunner

from ramps import __version__
from ramps.cli import app
from ramps.core.messages import PROTOCOL
from ramps.runtime.settings import load_settings
from ramps.runtime.transport import ZenohTransport, real_endpoint

runner = CliRunner()


def test_version_flag_prints_the_release_and_the_protocol():
    for args in (["--version"], ["version"]):
        res = runner.invoke(app, args)
        assert res.exit_code == 0, res.output
        assert res.output.strip() == f"ramps {__version__} (protocol {PROTOCOL})"


def test_a_program_module_that_raises_at_import_is_one_line_and_exit_2(tmp_path, monkeypatch):
    (tmp_path / "brokenplans.py").write_text('import os\n\nraise ValueError("no map file at /etc/robot/map.yaml")\n')
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(signal, "signal", lambda *a: None)  # the node's handlers stay out of pytest
    monkeypatch.setattr("ramps.runtime.node.prioritize", lambda nice: True)
    res = runner.invoke(app, ["node", "--robot", "t1", "--team", "first-hour", "--no-multicast", "--state-dir",
                              "off", "--program", "brokenplans:plan"], env={"COLUMNS": "400"})
    assert res.exit_code == 2, res.output
    [line] = [ln for ln in res.output.splitlines() if ln.startswith("error:")]
    assert line == ("error: cannot import 'brokenplans' for program 'brokenplans:plan': it raised ValueError: "
                    f"no map file at /etc/robot/map.yaml (at {tmp_path / 'brokenplans.py'}:3)")
    assert "Traceback" not in res.output


def test_port_zero_is_shown_as_the_port_the_listener_got():
    bound = [("0.0.0.0", 41234), ("127.0.0.1", 7447)]
    assert real_endpoint("tcp/0.0.0.0:0", bound) == "tcp/0.0.0.0:41234"
    assert real_endpoint("tcp/127.0.0.1:7447", bound) == "tcp/127.0.0.1:7447"  # a port of its own stays
    assert real_endpoint("tcp/10.0.0.5:0", bound) == "tcp/10.0.0.5:0"  # cannot tell: what was asked
    assert real_endpoint("udp/0.0.0.0:0", bound) == "udp/0.0.0.0:0"
    s = load_settings(flags={"team": "first-hour", "multicast": False, "listen": ["tcp/127.0.0.1:0"]},
                      environ={}, default_robot=False)
    t = ZenohTransport.open(s)
    try:
        [where] = t.locators()
        host, port = where.removeprefix("tcp/").rsplit(":", 1)
        assert host == "127.0.0.1" and int(port) > 0
        socket.create_connection((host, int(port)), timeout=2).close()  # it really listens there
    finally:
        t.close()


def test_help_of_ramps_connect_is_the_real_signature_and_says_what_each_argument_is():
    import inspect

    import ramps
    from ramps.runtime import client

    public, impl = inspect.signature(ramps.connect), inspect.signature(client.connect)
    assert [(p.name, p.kind, p.default) for p in public.parameters.values()] == [
        (p.name, p.kind, p.default) for p in impl.parameters.values()]
    doc = inspect.getdoc(ramps.connect)
    for name in public.parameters:
        assert f"\n{name}\n" in doc or f"\n{name}," in doc or f", {name}\n" in doc, name
    assert "Example" in doc and "team.submit(" in doc
    for method in ("submit", "map", "submit_async", "map_async", "options", "status", "pending", "close"):
        assert len(inspect.getdoc(getattr(client.Team, method)) or "") > 40, method
