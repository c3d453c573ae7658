"""The house's written rules that a reader meets first: the README stays short, and the project speaks of
itself alone (no tracker or session numbers outside the lab notes of docs/archive/ and git)."""

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
