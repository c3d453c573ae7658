"""Checkpoints: written atomically, the previous one kept, corrupt files refused with a clear error."""

from __future__ import annotations

import os
import shutil
from pathlib import Path
from typing import Any

import torch

from aslexp.files import atomic_path

FORMAT = "aslexp-ppo-1"


class CheckpointError(RuntimeError):
    """A checkpoint that cannot be used (missing, corrupt, or written by something else)."""


def save_checkpoint(path: str | os.PathLike, payload: dict[str, Any]) -> Path:
    """Write ``payload`` to ``path`` via a temporary file; the old file becomes ``<name>.prev``."""
    path = Path(path)
    with atomic_path(path) as tmp:
        torch.save({"format": FORMAT, **payload}, tmp)
        if path.exists():
            shutil.copy2(path, path.with_suffix(path.suffix + ".prev"))
    return path


def load_checkpoint(path: str | os.PathLike) -> dict[str, Any]:
    """Read a checkpoint written by :func:`save_checkpoint`; raise :class:`CheckpointError` otherwise."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"checkpoint not found: {path}")
    try:
        # Our own files hold numpy RNG state and plain dicts, hence weights_only=False.
        payload = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as exc:  # torch raises many types for truncated/garbled files
        prev = path.with_suffix(path.suffix + ".prev")
        hint = f"; the previous checkpoint {prev} may still be good" if prev.is_file() else ""
        raise CheckpointError(f"checkpoint {path} is corrupt or unreadable ({type(exc).__name__}: {exc}){hint}") from exc
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise CheckpointError(f"checkpoint {path} is not an {FORMAT} checkpoint")
    return payload
