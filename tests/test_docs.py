"""The README's and docs' relative links lead somewhere: each names a file of the tree, and
each `#anchor` a heading of the page it names (as GitHub makes them)."""

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
LINK = re.compile(r"\]\(([^)\s]+)\)")


def anchor(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation but - and _ dropped, spaces to -."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def prose(page: Path) -> str:
    """The page without its code blocks (a `# comment` there is no heading, a `](x)` no link)."""
    return re.sub(r"```.*?```", "", page.read_text(), flags=re.DOTALL)


def anchors(page: Path) -> set:
    return {anchor(line.lstrip("#")) for line in prose(page).splitlines() if re.match(r"#{1,6} ", line)}


def relative_links(page: Path) -> list:
    return [m for m in LINK.findall(prose(page)) if not re.match(r"[a-z]+:", m)]


def test_anchor_follows_github():
    assert anchor("What the model is given: `--state velocities` or `positions`") == (
        "what-the-model-is-given---state-velocities-or-positions"
    )
    assert anchor("The bundled checkpoints (velocity state)") == "the-bundled-checkpoints-velocity-state"


def broken_links(page: Path) -> list:
    """The relative links of `page` that name no file, or no heading of the page they name."""
    broken = []
    for link in relative_links(page):
        path, _, fragment = link.partition("#")
        target = (page.parent / path).resolve() if path else page
        if not target.exists() or (fragment and target.suffix == ".md" and fragment not in anchors(target)):
            broken.append(link)
    return broken


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_relative_links_resolve(page):
    assert not broken_links(page)


def test_a_broken_link_is_caught(tmp_path):
    (tmp_path / "other.md").write_text("## A part: `--flag`\n")
    page = tmp_path / "page.md"
    page.write_text(
        "# Title\n\n[ok](#title) [ok](other.md#a-part---flag) [gone](missing.md) "
        "[no such part](other.md#nowhere) [none here](#nowhere)\n```\n# not a heading\n[x](y.md)\n```\n"
    )
    assert broken_links(page) == ["missing.md", "other.md#nowhere", "#nowhere"]
