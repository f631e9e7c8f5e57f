"""Scenario files: the examples load, and every kind of mistake names its line."""

from __future__ import annotations

from pathlib import Path

import pytest

from ramps.sim.scenario import Scenario
from ramps.sim.scenario_file import ScenarioFileError, load_scenario, scenario_from_dict

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"

GOOD = """\
name: t
robots:
  - name: a
    cores: 4
  - name: b
    cores: 2
programs:
  - origin: a
    work: 10
"""


def write(tmp_path: Path, text: str, name: str = "s.yaml") -> Path:
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


def error(tmp_path: Path, text: str, name: str = "s.yaml") -> ScenarioFileError:
    with pytest.raises(ScenarioFileError) as info:
        load_scenario(write(tmp_path, text, name))
    return info.value


# -- valid files ----------------------------------------------------------------


def test_warehouse_example() -> None:
    s = load_scenario(EXAMPLES / "warehouse.yaml")
    assert isinstance(s, Scenario)
    team = s.team()
    assert [r.name for r in team] == ["r1", "r2", "r3", "r4", "r5"]
    assert all(r.cores == 4 and r.speed == 1.0 for r in team)
    assert sorted(r.background for r in team) == [0, 0, 0, 0, 8]
    (p,) = s.programs
    assert (p.count, p.work, p.payload, p.result, p.origin, p.at, p.spacing) == (15, 53, 2000, 1000, "r1", 0, 0.05)
    (f,) = s.faults
    assert (f.at, f.robot, f.kind) == (20, "r5", "crash")
    assert (s.policy, s.seed) == ("ramps", 1)


def test_big_team_example() -> None:
    s = load_scenario(str(EXAMPLES / "big-team.yaml"))
    team = s.team()
    assert len(team) == 1000
    assert team[0].name == "w1" and team[-1].name == "w1000"
    assert all(r.count is None for r in team)
    assert [p.origin for p in s.programs] == [f"w{i}" for i in range(1, 11)]
    assert sum(p.count for p in s.programs) == 10_000
    assert all(p.spacing == 0.01 and p.work == 53 for p in s.programs)


def test_good_file_and_defaults(tmp_path: Path) -> None:
    s = load_scenario(write(tmp_path, GOOD))
    assert [r.cores for r in s.team()] == [4, 2]
    assert s.programs[0].work == 10.0 and s.policy == "ramps"


def test_exponent_without_dot_is_a_float(tmp_path: Path) -> None:
    s = load_scenario(write(tmp_path, GOOD + "network: {bandwidth: 1e6}\n"))
    assert s.network.bandwidth == 1e6


def test_toml_file(tmp_path: Path) -> None:
    text = '[[robots]]\nname = "a"\n\n[[programs]]\norigin = "a"\n'
    assert load_scenario(write(tmp_path, text, "s.toml")).team()[0].name == "a"
    err = error(tmp_path, '[[robots]]\nname = "a"\n\n[[programs]]\norigin = "zz"\n', "s.toml")
    assert err.field == "$.programs[0].origin" and err.line is None and "zz" in err.message


def test_scenario_from_dict() -> None:
    s = scenario_from_dict({"robots": [{"name": "a"}], "programs": [{"origin": "a"}]})
    assert s.team()[0].name == "a"
    with pytest.raises(ScenarioFileError) as info:
        scenario_from_dict({"robots": [{"name": "a", "cores": 0}], "programs": [{"origin": "a"}]}, source="api")
    err = info.value
    assert (err.file, err.line, err.field) == ("api", None, "$.robots[0].cores")
    assert str(err) == "api: robots[0].cores: must be >= 1, got 0"


# -- errors: each names the right line and field ---------------------------------


def test_wrong_type(tmp_path: Path) -> None:
    err = error(tmp_path, GOOD.replace("cores: 2", 'cores: "two"'))
    assert (err.line, err.field) == (6, "$.robots[1].cores")
    assert str(err).endswith(":6: robots[1].cores: Expected `int`, got `str`")


def test_wrong_type_value_on_next_line(tmp_path: Path) -> None:
    err = error(tmp_path, GOOD.replace("cores: 2", 'cores:\n      "two"'))
    assert (err.line, err.field) == (7, "$.robots[1].cores")


def test_unknown_field_points_at_key_and_suggests(tmp_path: Path) -> None:
    err = error(tmp_path, GOOD.replace("cores: 2", "cpus: 2"))
    assert (err.line, err.field) == (6, "$.robots[1].cpus")
    assert "unknown field `cpus`" in err.message
    assert "did you mean `cores`?" in err.message
    assert "background" in err.message  # lists the valid fields


def test_unknown_top_level_and_nested_fields(tmp_path: Path) -> None:
    err = error(tmp_path, GOOD + "polcy: ramps\n")
    assert (err.line, err.field) == (10, "$.polcy") and "did you mean `policy`?" in err.message
    err = error(tmp_path, GOOD + "config:\n  heartbeat_priod: 1.0\n")
    assert (err.line, err.field) == (11, "$.config.heartbeat_priod")
    assert "did you mean `heartbeat_period`?" in err.message


def test_missing_required_field(tmp_path: Path) -> None:
    err = error(tmp_path, GOOD.replace("  - origin: a\n    work: 10", "  - work: 10\n    count: 2"))
    assert (err.line, err.field) == (8, "$.programs[0]")
    assert "missing required field `origin`" in err.message


def test_unknown_origin_robot(tmp_path: Path) -> None:
    err = error(tmp_path, GOOD.replace("origin: a", "origin: zz"))
    assert (err.line, err.field) == (8, "$.programs[0].origin")
    assert "unknown robot 'zz'" in err.message


def test_negative_cores(tmp_path: Path) -> None:
    err = error(tmp_path, GOOD.replace("cores: 2", "cores: -1"))
    assert (err.line, err.field) == (6, "$.robots[1].cores")
    assert "must be >= 1, got -1" in err.message


def test_unknown_fault_kind(tmp_path: Path) -> None:
    err = error(tmp_path, GOOD + "faults:\n  - {at: 1, robot: a, kind: boom}\n")
    assert (err.line, err.field) == (11, "$.faults[0].kind")


def test_duplicate_key(tmp_path: Path) -> None:
    err = error(tmp_path, GOOD.replace("    cores: 2\n", "    cores: 2\n    cores: 3\n"))
    assert err.line == 7
    assert "duplicate key `cores`" in err.message and "line 6" in err.message


def test_yaml_syntax_error(tmp_path: Path) -> None:
    err = error(tmp_path, GOOD.replace("  - name: b", "  - name: [b"))
    assert err.line is not None and 5 <= err.line <= 7
    assert "YAML syntax error" in err.message
    err = error(tmp_path, "robots:\n  - name: a\n bad: 1\n")
    assert err.line == 3


@pytest.mark.parametrize("text", ["", "\n\n", "# only a comment\n", "---\n"])
def test_empty_file(tmp_path: Path, text: str) -> None:
    err = error(tmp_path, text)
    assert "the file is empty" in err.message and err.line is None


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(ScenarioFileError) as info:
        load_scenario(tmp_path / "nope.yaml")
    assert "no such file" in info.value.message
    assert str(info.value).endswith("nope.yaml: no such file")


def test_not_utf8(tmp_path: Path) -> None:
    p = tmp_path / "s.yaml"
    p.write_bytes(b"name: t\nrobots: [\xff]\n")
    with pytest.raises(ScenarioFileError) as info:
        load_scenario(p)
    assert "not UTF-8" in info.value.message and info.value.line == 2


def test_top_level_list(tmp_path: Path) -> None:
    err = error(tmp_path, "- name: a\n- name: b\n")
    assert "must be a mapping" in err.message and "list" in err.message and err.line == 1


def test_bad_nested_config(tmp_path: Path) -> None:
    err = error(tmp_path, GOOD + "config: {heartbeat_timeout: 0.1}\n")
    assert err.line == 10
    assert err.field == "$.config.heartbeat_timeout"
    assert "heartbeat_period" in err.message


def test_non_string_key(tmp_path: Path) -> None:
    err = error(tmp_path, GOOD + "3: x\n")
    assert err.line == 10 and "keys must be strings" in err.message


def test_python_tags_are_refused(tmp_path: Path) -> None:
    err = error(tmp_path, GOOD.replace("name: t", "name: !!python/object/apply:os.getcwd []"))
    assert err.line == 1 and "YAML" in err.message


def test_str_without_line() -> None:
    err = ScenarioFileError("x.yaml", "boom", field="$")
    assert str(err) == "x.yaml: boom"
    assert str(ScenarioFileError("x.yaml", "boom", line=3, field="$.seed")) == "x.yaml:3: seed: boom"


def test_merge_keys_point_at_the_entry_that_counts(tmp_path: Path) -> None:
    text = "robots:\n  - &r\n    name: a\n    cores: 4\n  - <<: *r\n    name: b\n    cores: x\nprograms: [{origin: a}]\n"
    err = error(tmp_path, text)
    assert (err.line, err.field) == (7, "$.robots[1].cores")
    ok = load_scenario(write(tmp_path, text.replace("cores: x", "speed: 2.0")))
    assert [(r.name, r.cores, r.speed) for r in ok.team()] == [("a", 4, 1.0), ("b", 4, 2.0)]


def test_several_documents_are_refused(tmp_path: Path) -> None:
    err = error(tmp_path, GOOD + "---\n" + GOOD)
    assert err.line == 10 and "single document" in err.message
