"""The README and the manual (docs/) hold together: every relative link resolves (its file
exists; its #anchor names a heading of that file, slugged as GitHub does), no paragraph
stands in two files (each fact has one home), and the README stays a front page (at most
300 lines, no dated sitting or machine-load figure: those belong in docs/BENCHMARKS.md and
docs/CHANGELOG.md)."""

from __future__ import annotations

import re
from collections import defaultdict
from functools import cache
from pathlib import Path
from urllib.parse import unquote

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
PAGES = [README, *sorted((ROOT / "docs").rglob("*.md"))]
MIN_PARAGRAPH = 200  # characters, whitespace-normalised: shorter ones may well recur

FENCE = re.compile(r"^(```|~~~).*?^\1[^\n]*$", re.S | re.M)
INLINE_CODE = re.compile(r"`[^`\n]*`")
# [text](target) and ![alt](target), with an optional "title"; text may hold `code`.
LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
HEADING = re.compile(r"^(#{1,6})\s+(.*?)\s*#*\s*$", re.M)


def _prose(text: str) -> str:
    """The text outside fenced code blocks (links and headings there are not Markdown)."""
    return FENCE.sub("", text)


def slug(heading: str) -> str:
    """GitHub's anchor for a heading: the rendered text lower-cased, every character but
    letters, digits, `_`, `-` and spaces dropped, each space a `-`."""
    text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", heading)  # a link renders as its text
    text = re.sub(r"<[^>]+>", "", text)
    return re.sub(r"[^\w\- ]", "", text.strip().lower()).replace(" ", "-")


@cache
def anchors(path: Path) -> frozenset[str]:
    """Every heading's anchor in a file; a repeated slug gets -1, -2, ... as on GitHub."""
    seen: dict[str, int] = defaultdict(int)
    out = set()
    for _, text in HEADING.findall(_prose(path.read_text())):
        base = slug(text)
        out.add(base if not seen[base] else f"{base}-{seen[base]}")
        seen[base] += 1
    return frozenset(out)


def relative_links(path: Path) -> list[str]:
    # Code spans are blanked (a link's text may be one: [`x.md`](x.md) still matches).
    prose = INLINE_CODE.sub(lambda m: "` `", _prose(path.read_text()))
    return [t for t in LINK.findall(prose)
            if not re.match(r"^[a-z][a-z0-9+.-]*:", t, re.I)]  # http:, https:, mailto:


def broken_links(path: Path) -> list[str]:
    broken = []
    for target in relative_links(path):
        file_part, _, anchor = target.partition("#")
        dest = (path.parent / unquote(file_part)).resolve() if file_part else path
        if not dest.exists():
            broken.append(f"{target} (no such file)")
        elif anchor and dest.suffix == ".md" and unquote(anchor) not in anchors(dest):
            broken.append(f"{target} (no heading #{anchor} in {dest.name})")
    return broken


def paragraphs(text: str) -> list[str]:
    """The units a reader meets: blank-line separated blocks outside code, with each list
    item and each table row a unit of its own, whitespace folded."""
    units = []
    for block in re.split(r"\n\s*\n", _prose(text)):
        parts = re.split(r"\n(?=\s*(?:[-*+] |\d+\. |\|))", block)
        units += [" ".join(p.split()) for p in parts]
    return [u for u in units if len(u) >= MIN_PARAGRAPH]


def test_every_page_is_found():
    assert README in PAGES and (ROOT / "docs" / "index.md") in PAGES
    assert len(PAGES) >= 10


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_resolves(page):
    assert broken_links(page) == []


def test_the_manual_index_links_every_page():
    index = ROOT / "docs" / "index.md"
    linked = {(index.parent / t.partition("#")[0]).resolve() for t in relative_links(index)}
    missing = [str(p.relative_to(ROOT)) for p in PAGES
               if p not in (README, index) and p.resolve() not in linked]
    assert missing == []


def test_no_paragraph_stands_in_two_files():
    homes: dict[str, set[str]] = defaultdict(set)
    for page in PAGES:
        for unit in paragraphs(page.read_text()):
            homes[unit].add(str(page.relative_to(ROOT)))
    twice = {u[:80]: sorted(h) for u, h in homes.items() if len(h) > 1}
    assert twice == {}


def test_the_readme_is_a_front_page():
    text = README.read_text()
    assert len(text.splitlines()) <= 300
    assert re.findall(r"\b20\d\d-\d\d-\d\d\b", text) == []  # dated sittings: CHANGELOG
    assert re.findall(r"\bload(?: average)?:? \d", text, re.I) == []  # machine load


def test_the_checks_can_fail(tmp_path):
    """The link, anchor and paragraph checks catch what they are for."""
    (tmp_path / "a.md").write_text("# Top `x` (y)\n\n## Top x y\n\nsee [b](b.md), "
                                   "[here](#top-x-y-1), [gone](#nowhere), ![i](img.png), "
                                   "`[code](not-a-link.md)`\n\n```\n[fenced](no.md)\n```\n")
    assert anchors(tmp_path / "a.md") == {"top-x-y", "top-x-y-1"}
    assert broken_links(tmp_path / "a.md") == [
        "b.md (no such file)", "#nowhere (no heading #nowhere in a.md)",
        "img.png (no such file)"]
    long = "word " * 50
    assert paragraphs(f"intro\n\n{long}\n\n- {long}\n- short\n| {long} |\n") == [
        long.strip(), "- " + long.strip(), "| " + long.strip() + " |"]
    assert slug("M4 at large N: the dense F2 regime") == "m4-at-large-n-the-dense-f2-regime"
    assert slug("RK4 (`--dim 3`)") == "rk4---dim-3"
