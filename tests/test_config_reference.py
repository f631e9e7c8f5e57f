"""docs/configuration.md is what ``ramps config reference`` prints, and it documents
every setting, flag and environment variable of a node: a setting added without a
comment, or a page not regenerated, fails here."""

from __future__ import annotations

from pathlib import Path

import msgspec
from typer.testing import CliRunner

from ramps.cli import app
from ramps.cli.reference import COMMAND, field_comments, node_flags, reference
from ramps.core.config import RampsConfig
from ramps.runtime.settings import _ENV, CommandEntry, NodeSettings

PAGE = Path(__file__).resolve().parents[1] / "docs" / "configuration.md"


def test_the_committed_page_is_what_the_command_prints() -> None:
    printed = CliRunner().invoke(app, ["config", "reference"])
    assert printed.exit_code == 0, printed.output
    assert printed.output == reference()
    assert PAGE.read_text() == printed.output, f"docs/configuration.md is out of date: run `{COMMAND}`"


def test_every_setting_flag_and_variable_is_on_the_page() -> None:
    page = PAGE.read_text()
    for cls in (NodeSettings, CommandEntry, RampsConfig):
        for name in msgspec.structs.fields(cls):
            assert f"| `{name.name}` |" in page, name.name
    for var in _ENV:
        assert f"`{var}`" in page, var
    by_field, others = node_flags()
    for flags in [*by_field.values(), *(f for f, _ in others)]:
        for flag in flags:
            assert f"`{flag}`" in page, flag


def test_every_node_setting_has_a_comment_of_its_own() -> None:
    for cls in (NodeSettings, CommandEntry):
        missing = [name for name, text in field_comments(cls).items() if not text]
        assert not missing, f"{cls.__name__}: fields without a #: comment: {missing}"
