"""The house's written rules that a reader meets first: the README stays short, the docs pages fit their word
budget and each opens with what it is for, the project speaks of itself alone (no tracker or session
numbers outside the lab notes of docs/archive/ and git), and no function runs over 80 lines."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
README_WORDS = 700
# the word issue or session (any case, singular or plural) followed by a number
TRACKER = re.compile(r"\b(issues?|sessions?)\s+#?\d", re.IGNORECASE)
SPOKEN_OF = ["src", "conf", "sweeps", "bench", "scripts", "tests", "docs", ".ci"]
TEXT = {".py", ".yaml", ".yml", ".md", ".sh", ".toml", ".txt", ""}


def test_the_readme_is_read_in_minutes():
    words = len((ROOT / "README.md").read_text(encoding="utf-8").split())
    assert words <= README_WORDS, f"README.md has {words} words; at most {README_WORDS}"


def _spoken_files():
    yield from (ROOT / name for name in ("README.md", "CHANGELOG.md", "CONTRIBUTING.md", "BENCHMARKS.md",
                                         "pyproject.toml"))
    for top in SPOKEN_OF:
        for path in sorted((ROOT / top).rglob("*")):
            if (path.is_file() and path.suffix in TEXT and "archive" not in path.relative_to(ROOT).parts[:2]
                    and "__pycache__" not in path.parts):
                yield path


def test_no_tracker_or_session_number_outside_the_lab_notes():
    found = []
    for path in _spoken_files():
        if not path.is_file():
            continue
        for number, line in enumerate(path.read_text(encoding="utf-8", errors="replace").splitlines(), 1):
            if TRACKER.search(line) and path != Path(__file__):
                found.append(f"{path.relative_to(ROOT)}:{number}: {line.strip()[:120]}")
    assert not found, f"{len(found)} places cite a tracker or session number:\n" + "\n".join(found[:40])


DOCS_WORDS = 22_000
GENERATED_PAGES = {"results.md"}  # written by `aslexp report --results`, not by hand


def _pages():
    return [p for p in sorted((ROOT / "docs").glob("*.md")) if p.name not in GENERATED_PAGES]


def test_the_docs_pages_fit_their_word_budget():
    counts = {p.name: len(p.read_text(encoding="utf-8").split()) for p in _pages()}  # as `wc -w` counts
    total = sum(counts.values())
    assert total <= DOCS_WORDS, f"the hand-written docs pages hold {total} words, at most {DOCS_WORDS}; {counts}"


def _opening_paragraph(text: str) -> str:
    """The first block after the page's `# ` title: empty when there is none, or it is a heading, code,
    a table, a list or an image."""
    lines = text.splitlines()
    if not lines or not lines[0].startswith("# "):
        return ""
    rest = "\n".join(lines[1:]).strip()
    block = rest.split("\n\n", 1)[0] if rest else ""
    return "" if block.startswith(("#", "```", "|", "-", "*", "!", "<")) else block


def test_every_docs_page_opens_with_what_it_is_for():
    missing = [p.name for p in _pages() if not _opening_paragraph(p.read_text(encoding="utf-8"))]
    assert not missing, f"pages whose `# ` title is not followed by a paragraph saying what they are for: {missing}"


def test_an_opening_is_a_paragraph_not_a_heading_or_code():
    assert _opening_paragraph("# T\n\nThis page is for X.\n\n## A\n") == "This page is for X."
    assert _opening_paragraph("# T\n\n```\ncode\n```\n") == ""
    assert _opening_paragraph("# T\n\n## A\n") == ""
    assert _opening_paragraph("no title\n\ntext\n") == ""


FUNCTION_LINES = 80


def test_no_function_in_the_package_is_over_80_lines():
    """A function a reader takes in at once: each of src/'s is at most 80 lines, its docstring included."""
    import ast

    long = []
    for path in sorted((ROOT / "src").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                lines = node.end_lineno - node.lineno + 1
                if lines > FUNCTION_LINES:
                    long.append(f"{path.relative_to(ROOT)}:{node.lineno} {node.name} ({lines} lines)")
    assert not long, f"functions over {FUNCTION_LINES} lines (split them where the work splits): {long}"
