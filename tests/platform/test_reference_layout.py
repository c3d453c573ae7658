"""docs/reference.md's Layout block is the tree: every room under src/aslexp/ and every top-level
folder of the repository is named there, and every name there exists."""

from __future__ import annotations

import fnmatch
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = ROOT / "src" / "aslexp"
REFERENCE = ROOT / "docs" / "reference.md"
NOT_ROOMS = {"__pycache__", "_conf"}  # _conf: conf/ as the installed wheel carries it


def layout_block(text: str) -> list[str]:
    """The lines of the first fenced block after the heading "## Layout"."""
    section = text.split("\n## Layout\n", 1)[1]
    return section.split("```", 2)[1].strip("\n").splitlines()


def named(lines: list[str]) -> tuple[set[str], set[str]]:
    """(top-level names, names under src/aslexp/) of a Layout block: a top-level entry starts at the
    line's first column, an entry of src/aslexp/ two spaces in (``folder/`` or ``module.py``, a comma
    list allowed); the lines indented further are descriptions."""
    top, inside = set(), set()
    for line in lines:
        if not line.strip():
            continue
        if not line.startswith(" "):
            top.add(line.split()[0])
        elif re.match(r"  \S", line):
            names = re.match(r"[\w.]+(?:/|\.py)(?:, [\w.]+(?:/|\.py))*", line.strip())
            assert names, f"docs/reference.md's Layout: {line.strip()!r} names no folder/ or module.py"
            inside |= set(names.group(0).split(", "))
    return top, inside


def ignored(name: str) -> bool:
    """Whether the repository's .gitignore ignores a top-level folder ``name``."""
    patterns = [p.strip().rstrip("/") for p in (ROOT / ".gitignore").read_text(encoding="utf-8").splitlines()
                if p.strip() and not p.startswith("#")]
    return any(fnmatch.fnmatch(name, pattern) for pattern in patterns)


def test_the_block_is_read_as_its_names():
    top, inside = named(layout_block(REFERENCE.read_text(encoding="utf-8")))
    assert {"conf/", "src/aslexp/", "tests/", "docs/"} <= top
    assert {"cli.py", "jobs/", "recognition/", "files.py", "seeding.py", "runfile.py"} <= inside
    assert not any(" " in name for name in top | inside), sorted(top | inside)


def test_every_room_under_src_aslexp_is_in_the_layout_block():
    _, inside = named(layout_block(REFERENCE.read_text(encoding="utf-8")))
    rooms = {f"{p.name}/" for p in PACKAGE.iterdir() if p.is_dir() and (p / "__init__.py").is_file()
             and p.name not in NOT_ROOMS}
    missing = sorted(rooms - inside)
    assert not missing, f"rooms of src/aslexp/ missing from docs/reference.md's Layout: {missing}"


def test_every_top_level_folder_is_in_the_layout_block():
    top, _ = named(layout_block(REFERENCE.read_text(encoding="utf-8")))
    folders = {f"{p.name}/" for p in ROOT.iterdir()
               if p.is_dir() and not p.name.startswith(".") and not ignored(p.name)}
    folders.discard("src/")  # named by its packages: src/aslexp/, src/hydra_plugins/
    source = {f"src/{p.name}/" for p in (ROOT / "src").iterdir() if p.is_dir() and not ignored(p.name)}
    missing = (folders | source) - top
    assert not missing, f"top-level folders missing from docs/reference.md's Layout: {sorted(missing)}"


def test_every_name_in_the_layout_block_exists():
    top, inside = named(layout_block(REFERENCE.read_text(encoding="utf-8")))
    gone = [name for name in top if not (ROOT / name).exists()]
    gone += [f"src/aslexp/{name}" for name in inside if not (PACKAGE / name).exists()]
    assert not gone, f"docs/reference.md's Layout names what is not in the tree: {sorted(gone)}"
