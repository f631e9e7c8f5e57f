"""docs/ is a manual with an index, and every relative link in it holds.

The README is a front page that links into docs/ and examples/; docs/README.md is the
manual's index. Every relative link in the README, the CHANGELOG and docs/ (lab notes too)
points at a file that exists inside the repository; every user page (a Markdown file directly
in docs/) is reachable from the index by links between user pages; dated notes and result
data live under docs/lab/, named ``YYYY-MM-DD-name.ext``, and none sit beside the user pages.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
INDEX = DOCS / "README.md"
PAGES = [ROOT / "README.md", ROOT / "CHANGELOG.md", *sorted(DOCS.glob("**/*.md"))]
USER_PAGES = sorted(DOCS.glob("*.md"))
LINK = re.compile(r"\]\(([^)\s]+)\)")
DATED = re.compile(r"\d{4}-\d{2}-\d{2}-[a-z0-9][a-z0-9.-]*\.[a-z]+")


def links(page: Path) -> list[Path]:
    """The files a page links to (URLs and same-page anchors left out)."""
    out = []
    for target in LINK.findall(page.read_text()):
        if re.match(r"[a-z]+:", target) or target.startswith("#"):
            continue
        out.append((page.parent / target.split("#")[0]).resolve())
    return out


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_resolve_inside_the_repository(page: Path) -> None:
    for path in links(page):
        assert path.is_relative_to(ROOT), f"{page.name} links outside the repository: {path}"
        assert path.exists(), f"{page.name} links to a missing file: {path.relative_to(ROOT)}"


def test_every_user_page_is_reachable_from_the_index() -> None:
    seen, todo = {INDEX}, [INDEX]
    while todo:
        for path in links(todo.pop()):
            if path.parent == DOCS and path.suffix == ".md" and path not in seen:
                seen.add(path)
                todo.append(path)
    missing = [p.name for p in USER_PAGES if p not in seen]
    assert not missing, f"user pages no link from docs/README.md leads to: {missing}"


def test_the_readme_links_the_manual() -> None:
    assert INDEX in links(ROOT / "README.md")


def test_no_data_and_no_dated_notes_beside_the_user_pages() -> None:
    beside = [p.name for p in DOCS.iterdir() if p.is_file() and p.suffix != ".md"]
    assert not beside, f"only user pages sit in docs/ (data goes to docs/lab/): {beside}"
    dated = [p.name for p in USER_PAGES if re.search(r"\d{4}-\d{2}-\d{2}", p.name)]
    assert not dated, f"dated notes go to docs/lab/: {dated}"
    stray = [str(p.relative_to(DOCS)) for p in DOCS.glob("**/*.json") if p.parent.name not in ("lab", "grafana")]
    assert not stray, f"JSON results go to docs/lab/: {stray}"


def test_user_pages_do_not_open_with_their_history() -> None:
    for page in USER_PAGES:
        opening = "\n".join(page.read_text().splitlines()[:6])
        assert not re.search(r"\bDated\b|moved from the README", opening, re.I), page.name


def test_lab_files_follow_one_date_convention() -> None:
    lab = DOCS / "lab"
    odd = [p.name for p in lab.iterdir() if p.name != "README.md" and not DATED.fullmatch(p.name)]
    assert not odd, f"lab files are named YYYY-MM-DD-name.ext: {odd}"
    listed = set(links(lab / "README.md"))
    unlisted = [p.name for p in lab.glob("*.md") if p.name != "README.md" and p.resolve() not in listed]
    assert not unlisted, f"lab notes missing from docs/lab/README.md: {unlisted}"


def test_the_readme_stays_a_front_page() -> None:
    assert len((ROOT / "README.md").read_text().splitlines()) <= 160
