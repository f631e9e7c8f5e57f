"""``ramps config check FILE``: every problem of a node's config file, one line
each, with the node's own checks (ramps.runtime.config_check)."""

from __future__ import annotations

from pathlib import Path

from typer.testing import CliRunner

from ramps.cli import app
from ramps.runtime import security as sec
from ramps.runtime.config_check import check_config, read_env_file

EXAMPLES = Path(__file__).resolve().parents[1] / "packaging" / "systemd"
runner = CliRunner()


def invoke(*args: str):
    return runner.invoke(app, ["config", "check", *args], catch_exceptions=False)


def write(tmp_path: Path, text: str, name: str = "node.toml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def test_the_shipped_example_is_ok_and_the_summary_names_the_effective_settings():
    res = invoke(str(EXAMPLES / "node.toml"))
    assert res.exit_code == 0, res.output
    lines = res.stdout.splitlines()
    assert lines[0] == f"ok: {EXAMPLES / 'node.toml'}"
    rows = {line.split()[0]: line.split(None, 1)[1] for line in lines[1:]}
    assert rows["robot"] == "r1" and rows["team"] == "warehouse"
    assert rows["connect"] == "tcp/192.168.1.12:7447" and rows["listen"] == "tcp/0.0.0.0:7447"
    assert rows["security"].startswith("INSECURE")
    assert "route_plan" in rows["programs"]


def test_the_environment_file_overrides_the_file_as_the_service_reads_it(tmp_path):
    env = write(tmp_path, "# the service's\nRAMPS_TEAM=yard\nexport RAMPS_CONNECT='tcp/10.0.0.2:7447'\n", "node.env")
    assert read_env_file(env) == {"RAMPS_TEAM": "yard", "RAMPS_CONNECT": "tcp/10.0.0.2:7447"}
    res = invoke(str(EXAMPLES / "node.toml"), "--env-file", str(env), "--json")
    assert res.exit_code == 0, res.output
    assert '"team":"yard"' in res.stdout and '"connect":["tcp/10.0.0.2:7447"]' in res.stdout
    bad = write(tmp_path, "RAMPS_CORES=many\n", "bad.env")
    res = invoke(str(EXAMPLES / "node.toml"), "--env-file", str(bad))
    assert res.exit_code == 2 and "RAMPS_CORES='many'" in res.output


def test_every_problem_is_named_on_its_own_line(tmp_path):
    f = write(tmp_path, """
robot = "r1"
lisen = ["tcp/0.0.0.0:7447"]
connect = ["tcp/192.168.1.12"]
cores = "four"
lease_ms = 50
policy = "fastest"
programs = ["nosuchpkg.plans:replan"]
[core]
heartbeat_timout = 2.0
[commands.detect]
path = "/nonexistent/detect"
timout = 3
""")
    res = invoke(str(f))
    assert res.exit_code == 2
    lines = [line for line in res.output.splitlines() if line.startswith("error:")]
    expect = [
        "lisen: unknown setting (did you mean listen?)",
        "core.heartbeat_timout: unknown setting (did you mean core.heartbeat_timeout?)",
        "commands.detect.timout: unknown setting (did you mean commands.detect.timeout?)",
        "cores: Expected `int | null`, got `str`",
        "lease_ms: lease_ms must be >= 100, got 50",
        "connect: endpoint 'tcp/192.168.1.12' needs a host and a port",
        "policy: unknown policy 'fastest'",
        "programs: nosuchpkg.plans:replan: cannot import",
        "commands.detect: command '/nonexistent/detect': no such file",
    ]
    assert len(lines) == len(expect), res.output
    for want in expect:
        assert any(line.startswith(f"error: {f}: {want}") for line in lines), (want, res.output)


def test_secure_mode_needs_tls_and_this_robots_credentials(tmp_path):
    res = invoke(str(write(tmp_path, 'robot = "r1"\nsecure = true\n')))
    assert res.exit_code == 2 and "secure: secure mode needs this robot's credentials" in res.output
    res = invoke(str(write(tmp_path, 'robot = "r1"\nconnect = ["tls/10.0.0.2:7447"]\n')))
    assert res.exit_code == 2 and "TLS links need secure mode" in res.output
    ca = tmp_path / "ca"
    sec.create_ca(ca, "warehouse")
    sec.issue(ca, "r1")
    good = write(tmp_path, f'robot = "r1"\nteam = "warehouse"\nsecure = true\ncredentials = "{ca / "r1"}"\n'
                           'listen = ["tls/0.0.0.0:7447"]\n')
    res = invoke(str(good))
    assert res.exit_code == 0, res.output
    assert "secure: TLS with team certificates" in res.stdout
    # the same file on robot r2 (another robot's certificate), or with a missing directory
    assert not check_config(good, robot="r2").ok
    missing = write(tmp_path, good.read_text().replace(str(ca / "r1"), str(tmp_path / "nowhere")))
    problems = check_config(missing).problems
    assert len(problems) == 1 and problems[0].setting == "credentials" and "does not exist" in problems[0].message


def test_unreadable_and_malformed_files(tmp_path):
    res = invoke(str(tmp_path / "nothere.toml"))
    assert res.exit_code == 2 and "cannot read" in res.output and "No such file" in res.output
    res = invoke(str(write(tmp_path, 'robot = "r1"\n[core\n')))
    assert res.exit_code == 2 and "not valid TOML" in res.output and "line 2" in res.output
    assert len([line for line in res.output.splitlines() if line.startswith("error:")]) == 1
