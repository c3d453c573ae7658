"""Every relative Markdown link of the README and docs/**/*.md points at a file that exists and, where
it names an anchor in a Markdown file, at a heading (GitHub's anchor of it) or an `<a id>` there
(the wing pages keep their diaries in docs/archive/, and the links must follow)."""

from __future__ import annotations

import re
from functools import lru_cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")


def _prose(text: str) -> list[str]:
    """The lines outside fenced code blocks, inline code spans removed."""
    lines, fenced = [], False
    for line in text.splitlines():
        if line.lstrip().startswith("```"):
            fenced = not fenced
        elif not fenced:
            lines.append(re.sub(r"`[^`]*`", "", line))
    return lines


def _slug(heading: str) -> str:
    """GitHub's anchor of a Markdown heading (before the -1, -2 of repeated headings)."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


@lru_cache(maxsize=None)
def anchors(path: Path) -> frozenset[str]:
    text = path.read_text(encoding="utf-8")
    found, seen = set(re.findall(r"<a\s+(?:id|name)=\"([^\"]+)\"", text)), {}
    fenced = False
    for line in text.splitlines():  # headings with inline code keep its text in the anchor
        if line.lstrip().startswith("```"):
            fenced = not fenced
        elif not fenced and re.match(r"#{1,6} ", line):
            slug = _slug(line.lstrip("#"))
            found.add(f"{slug}-{seen[slug]}" if slug in seen else slug)
            seen[slug] = seen.get(slug, 0) + 1
    return frozenset(found)


def links(doc: Path) -> list[str]:
    return [target for line in _prose(doc.read_text(encoding="utf-8")) for target in LINK.findall(line)
            if not re.match(r"[a-z][a-z0-9+.-]*:", target)]  # http:, https:, mailto: are not checked here


@pytest.mark.parametrize("doc", DOCS, ids=[str(d.relative_to(ROOT)) for d in DOCS])
def test_every_relative_link_points_at_a_file_and_a_heading_that_exist(doc):
    broken = []
    for target in links(doc):
        path, _, anchor = target.partition("#")
        file = (doc.parent / path).resolve() if path else doc
        if not file.exists():
            broken.append(f"{target}: no such file")
        elif anchor and file.suffix == ".md" and anchor not in anchors(file):
            broken.append(f"{target}: no heading or <a id> with that anchor in {file}")
    assert not broken, "\n".join(broken)


def test_the_anchors_are_githubs():
    assert _slug(" The thesis' signs, like for like (table 6.7)") == "the-thesis-signs-like-for-like-table-67"
    assert _slug("Variant: the root in view (`experiment=archive/x_y`)") == "variant-the-root-in-view-experimentarchivex_y"
    assert _slug("Probe: log-std -4, on two") == "probe-log-std--4-on-two"
