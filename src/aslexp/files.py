"""Atomic file writes: one place for the write-to-temporary-then-rename pattern (and JSON
written that way: :func:`write_json`, with :func:`read_json`, for every layer).

The temporary file sits beside the target (``os.replace`` is atomic only within one file
system) and its name is unique per writer: two processes writing the same target (two sweep
workers writing ``sweep.json``, say) never share, truncate or rename each other's temporary.
The last writer wins; no reader ever sees half a file.

A write that fails names its file (:func:`naming_errors`: an ``OSError`` from ``write()`` carries
no path of its own), and :func:`describe_os_error` says "disk full" when the device is full.
"""

from __future__ import annotations

import errno
import json
import os
import secrets
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any


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
        with naming_errors(path):
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


def _json_default(obj: Any) -> Any:
    if hasattr(obj, "item"):
        return obj.item()
    if hasattr(obj, "tolist"):
        return obj.tolist()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def write_json(path: str | os.PathLike, payload: Any) -> None:
    """Write JSON atomically (a crash never leaves half a file); numpy values and paths as their
    plain values. The folder must exist (run.json, sweep.json and metrics.json sit in theirs)."""
    with atomic_path(path, make_parents=False) as tmp, open(tmp, "w", encoding="utf-8") as fh:
        json.dump(payload, fh, indent=2, default=_json_default, allow_nan=True)
        fh.write("\n")


def read_json(path: str | os.PathLike) -> Any:
    with open(path, encoding="utf-8") as fh:
        return json.load(fh)


def write_rows_csv(path: str | os.PathLike, rows: list[dict[str, Any]], fields: list[str]) -> None:
    """One CSV row per dict (the first row's keys as the header; ``fields`` when there is none)."""
    import csv

    with open(path, "w", newline="", encoding="utf-8") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]) if rows else fields)
        writer.writeheader()
        writer.writerows(rows)


# --------------------------------------------------------------------------- failed writes

_FULL = {errno.ENOSPC: "disk full", errno.EDQUOT: "disk quota exceeded"}


@contextmanager
def naming_errors(path: str | os.PathLike) -> Iterator[None]:
    """An ``OSError`` raised inside names ``path`` (``write()`` and ``close()`` errors name no file)."""
    try:
        yield
    except OSError as error:
        if error.filename is None:
            error.filename = os.fspath(path)
        raise


class _PythonWrites:
    """A file that numpy does not recognise as one: ``np.save`` then writes through Python's
    ``write()``, whose ``OSError`` keeps its errno (``ndarray.tofile`` reports a full disk only as
    ``N requested and M written``)."""

    def __init__(self, handle) -> None:
        self.write = handle.write


def save_npy(path: str | os.PathLike, array) -> Path:
    """``np.save(path, array)`` whose failure names ``path`` and keeps its errno (disk full)."""
    import numpy as np

    path = Path(path)
    with naming_errors(path), open(path, "wb") as handle:
        np.save(_PythonWrites(handle), array, allow_pickle=False)
    return path


def write_text(path: str | os.PathLike, text: str) -> Path:
    """``Path.write_text`` (UTF-8) whose failure names ``path``."""
    path = Path(path)
    with naming_errors(path):
        path.write_text(text, encoding="utf-8")
    return path


def describe_os_error(error: OSError) -> str:
    """An ``OSError`` as one line naming its file(s): ``disk full: cannot write FILE ([Errno 28] No
    space left on device)`` for a full device (a full quota: ``disk quota exceeded``), else
    ``TypeName: message: 'FILE'``."""
    text = " ".join(line.strip() for line in str(error).splitlines() if line.strip()) or type(error).__name__
    names = [os.fsdecode(f) if isinstance(f, (str, bytes, os.PathLike)) else str(f)
             for f in (error.filename, error.filename2) if f is not None]
    if error.errno in _FULL:
        reason = f"[Errno {error.errno}] {error.strerror or os.strerror(error.errno)}"
        return f"{_FULL[error.errno]}: cannot write {' -> '.join(names)} ({reason})" if names else \
            f"{_FULL[error.errno]}: {reason}"
    missing = [name for name in names if name not in text]
    if missing:
        text += ": " + ", ".join(missing)
    return f"{type(error).__name__}: {text}"
