"""Atomic file writes: one place for the write-to-temporary-then-rename pattern.

The temporary file sits beside the target (``os.replace`` is atomic only within one file
system) and its name is unique per writer: two processes writing the same target (two sweep
workers writing ``sweep.json``, say) never share, truncate or rename each other's temporary.
The last writer wins; no reader ever sees half a file.
"""

from __future__ import annotations

import os
import secrets
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path


@contextmanager
def atomic_path(path: str | os.PathLike, make_parents: bool = True) -> Iterator[Path]:
    """Yield a temporary path to write; on success it replaces ``path``, on error it is removed.

    The temporary name starts with a dot and ends in ``.tmp`` so that globs for finished files
    (``*.json``, ``*.npy``) never match it.
    """
    path = Path(path)
    if make_parents:
        path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{secrets.token_hex(4)}.tmp")
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def atomic_write_text(path: str | os.PathLike, text: str) -> Path:
    """Write ``text`` (UTF-8) to ``path`` atomically and return the path."""
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return path
