"""The state diagram in the docs is generated from the transition table and
must not drift from it."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from ramps.core import diagram
from ramps.core.program import TRANSITIONS, Event, ProgramState, Transition

DOC = Path(__file__).resolve().parents[1] / "docs" / "state-machine.md"
HOW = f"regenerate it with: {diagram.COMMAND}"


def _between_markers(text: str) -> str:
    assert diagram.BEGIN in text and diagram.END in text, f"{DOC} lost its generated-section markers; {HOW}"
    return text.split(diagram.BEGIN, 1)[1].split(diagram.END, 1)[0].strip("\n")


def test_docs_page_is_up_to_date() -> None:
    assert DOC.exists(), f"{DOC} is missing; {HOW}"
    text = DOC.read_text(encoding="utf-8")
    assert _between_markers(text) == diagram.generated_block().strip("\n"), (
        f"{DOC} is out of date with ramps.core.program.TRANSITIONS; {HOW}")
    assert text == diagram.markdown(), f"{DOC} differs from what ramps.core.diagram generates; {HOW}"


def test_every_legal_transition_is_an_edge() -> None:
    text = diagram.mermaid()
    assert text.startswith("stateDiagram-v2\n")
    assert "    [*] --> offered: submit" in text
    for state, row in TRANSITIONS.items():
        for event in row:
            assert f"    {state.value} --> " in text and f": {event.value}" in text, (state, event)
    edges = diagram.edges()
    assert {(s, e) for s, e, *_ in edges} == {(s, e) for s, row in TRANSITIONS.items() for e in row}
    for state in (ProgramState.DONE, ProgramState.FAILED):
        assert f"    {state.value} --> [*]" in text


@pytest.mark.parametrize("state, event, target", [
    ("offered", "accepted", "running"),
    ("offered", "connect_timeout", "backoff"),
    ("running", "heartbeat_timeout", "backoff"),
    ("running", "result", "done"),
    ("running", "result", "failed"),
    ("offered", "rejected", "offered"),
    ("offered", "rejected", "failed"),
    ("backoff", "backoff_done", "offered"),
    ("backoff", "cancel", "failed"),
    ("running", "accepted", "running"),  # ignored duplicate: stays
    ("moving", "result", "running"),  # the new copy's worker died: the old copy runs on
])
def test_known_edges(state: str, event: str, target: str) -> None:
    assert any(line.startswith(f"    {state} --> {target}: {event}") for line in diagram.mermaid().splitlines())


def test_a_transition_without_outcomes_is_an_error() -> None:
    table = {ProgramState.OFFERED: {Event.RELOCATE: Transition("on_teleport", ())}}
    with pytest.raises(ValueError, match="'offered'.*'relocate'.*on_teleport"):
        diagram.mermaid(table)


def test_every_allowed_next_state_is_drawn() -> None:
    """What the origin checks at run time and what the page shows are the same set."""
    drawn = {(s, e, t) for s, e, _h, t, _w in diagram.edges()}
    checked = {(s, e, t) for s, row in TRANSITIONS.items() for e, tr in row.items() for t in tr.allowed(s)}
    assert drawn == checked


def test_main_prints_the_page() -> None:
    out = subprocess.run([sys.executable, "-m", "ramps.core.diagram"], capture_output=True, text=True,
                         check=True).stdout
    assert out == diagram.markdown()
