"""Programs registered by name: decorator, module:function, entry points, argument checks."""

from __future__ import annotations

import time

import pytest

from ramps.errors import BadArguments, ConfigError, ProgramNotFound
from ramps.runtime.registry import (
    MAX_ARGS_BYTES,
    ProgramSpec,
    Registry,
    decode_args,
    encode_args,
    program,
    resolve,
)


def test_entry_points_group_registers_installed_programs(tmp_path, monkeypatch):
    (tmp_path / "fleetprogs.py").write_text("def square(x: int) -> int:\n    return x * x\n")
    dist = tmp_path / "fleetprogs-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: fleetprogs\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text("[ramps.programs]\nsquare = fleetprogs:square\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    reg = Registry()
    reg.load_entry_points()
    assert "square" in reg
    assert reg.get("square").function()(x=7) == 49


def test_module_function_targets_are_checked_when_registered():
    reg = Registry()
    spec = reg.add_target("json:dumps", work=0.5)
    assert spec.name == "dumps" and spec.work == 0.5
    with pytest.raises(ConfigError, match="must look like"):
        reg.add_target("json.dumps")
    with pytest.raises(ConfigError, match="cannot import"):
        reg.add_target("no_such_module_xyz:f")
    with pytest.raises(ConfigError, match="has no"):
        resolve("json:no_such_function")


def test_decorator_refuses_functions_defined_in_main():
    def f() -> None: ...

    f.__module__ = "__main__"
    with pytest.raises(ConfigError, match="installed on every robot"):
        program()(f)


def test_unknown_program_names_the_known_ones():
    reg = Registry({"a": ProgramSpec("a", "json:dumps")})
    with pytest.raises(ProgramNotFound, match=r"no program 'b' is registered \(known: a\)"):
        reg.get("b")


def test_arguments_checked_against_the_signature_and_encoded_without_pickle():
    spec = ProgramSpec("sleep", "time:sleep")  # builtin: no keyword signature
    spec_py = ProgramSpec("f", "ramps.programs.burn:burn")
    data = encode_args(spec_py, {"seconds": 0.1})
    assert decode_args(data) == {"seconds": 0.1}
    with pytest.raises(BadArguments, match="unexpected keyword"):
        encode_args(spec_py, {"secs": 1})
    with pytest.raises(BadArguments, match="msgpack only, never pickle"):
        encode_args(spec_py, {"seconds": object()})
    with pytest.raises(BadArguments, match="limit"):
        encode_args(spec_py, {"seconds": 1.0, "units": None} | {}, max_bytes=4)
    with pytest.raises(BadArguments, match="mapping"):
        decode_args(b"\x93\x01\x02\x03")  # a msgpack list, not a mapping
    assert spec.name == "sleep" and 5_000_000 < MAX_ARGS_BYTES < 8 * 1024 * 1024  # 5 MB fits, one message holds it


@pytest.mark.slow
def test_a_real_node_reports_per_core_load_memory_and_load_average():
    from ramps.testing import LocalTeam

    with LocalTeam(1, speed=1.0) as team:
        client = team.client()
        try:
            deadline = time.monotonic() + 10
            while time.monotonic() < deadline:
                rows = [r for r in client.status().robots if r.cores]
                if rows:
                    break
                time.sleep(0.1)
            [row] = rows
            assert len(row.cpu_per_core) >= 1 and all(0.0 <= c <= 1.0 for c in row.cpu_per_core)
            assert row.mem_free > 0 and row.load_avg >= 0.0
        finally:
            client.close()
    assert not team.log_dir.exists()  # a clean close leaves no temp log dir behind


@pytest.mark.slow
def test_a_local_team_keeps_its_node_logs_when_it_ends_in_an_error():
    import shutil

    from ramps.testing import LocalTeam

    with pytest.raises(RuntimeError, match="boom"):
        with LocalTeam(1, speed=1.0) as team:
            raise RuntimeError("boom")
    try:
        assert (team.log_dir / "r1.log").exists()
    finally:
        shutil.rmtree(team.log_dir, ignore_errors=True)


def test_five_megabytes_of_parameters_fit_and_a_node_limit_beyond_one_message_is_refused(tmp_path):
    from ramps.runtime.settings import load_settings

    spec = Registry().add_target("ramps.testbed.slowlink:crunch")  # data: bytes, units: float
    assert len(encode_args(spec, {"data": b"\x00" * 5_000_000})) > 5_000_000
    with pytest.raises(BadArguments, match="limit"):
        encode_args(spec, {"data": b"\x00" * MAX_ARGS_BYTES})
    assert load_settings(environ={}, default_robot=False).max_args_bytes == MAX_ARGS_BYTES
    cfg = tmp_path / "node.toml"
    cfg.write_text("max_args_bytes = 9000000\n")
    with pytest.raises(ConfigError, match="max_args_bytes must be 1..8323072"):
        load_settings(config_file=cfg, environ={}, default_robot=False)
    cfg.write_text("max_args_bytes = 100000\n")
    assert load_settings(config_file=cfg, environ={}, default_robot=False).max_args_bytes == 100_000
