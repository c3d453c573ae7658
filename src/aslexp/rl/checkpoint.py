"""Checkpoints: written atomically, the previous one kept, corrupt files refused with a clear error.

A checkpoint holds tensors and plain data only (dicts, lists, tuples, str, int, float, bool,
None), and is read with ``torch.load(weights_only=True)``: a file that needs anything else to
unpickle (a hostile pickle whose ``__reduce__`` runs a command, a numpy object) is refused, never
executed. :func:`save_checkpoint` turns numpy scalars and arrays into Python numbers and tensors
and refuses any other object, so every file it writes loads that way.
"""

from __future__ import annotations

import os
import pickle
import re
import shutil
from collections import OrderedDict
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch

from aslexp.errors import DataError
from aslexp.files import atomic_path

FORMAT = "aslexp-ppo-2"  # -2: plain data checked at save, read with weights_only=True
# aslexp-ppo-1 files (the same entries, not checked at save) load when weights_only accepts them.
READABLE_FORMATS = (FORMAT, "aslexp-ppo-1")

_PLAIN = (str, int, float, bool, type(None), torch.dtype, torch.device)
_REFUSED_GLOBAL = re.compile(r"GLOBAL ([\w.]+)")


class CheckpointError(DataError):
    """A checkpoint that cannot be used (missing, corrupt, unsafe, or written by something else)."""


def plain(value: Any, where: str = "payload") -> Any:
    """``value`` as what ``torch.load(weights_only=True)`` reads back: tensors, plain containers
    and scalars; numpy scalars become Python numbers, numpy arrays tensors. Anything else raises
    TypeError naming where it sits (``where``)."""
    if isinstance(value, np.generic):  # before the plain types: np.float64 is a float subclass
        return value.item()
    if isinstance(value, torch.Tensor) or type(value) in _PLAIN:  # a subclass (an enum) would pickle its class
        return value
    if isinstance(value, np.ndarray):
        return torch.from_numpy(np.array(value))  # a copy: the checkpoint never aliases live state
    if isinstance(value, Mapping):
        items = {key: plain(item, f"{where}[{key!r}]") for key, item in value.items()}
        for key in items:
            if not isinstance(key, (str, int, float, bool, type(None))):
                raise TypeError(f"checkpoint {where}: key {key!r} is a {type(key).__name__}")
        return _like_mapping(value, items)
    if isinstance(value, (list, tuple)):
        items = [plain(item, f"{where}[{i}]") for i, item in enumerate(value)]
        return items if isinstance(value, list) else tuple(items)
    raise TypeError(f"checkpoint {where}: a {type(value).__module__}.{type(value).__qualname__} is not "
                    "plain data (tensors, dicts, lists, tuples, str, int, float, bool, None)")


def _like_mapping(original: Mapping, items: dict) -> dict:
    """An OrderedDict (a state_dict) stays one, with its ``_metadata``; other mappings become dicts."""
    if isinstance(original, OrderedDict):
        result = OrderedDict(items)
        metadata = getattr(original, "_metadata", None)
        if metadata is not None:
            result._metadata = plain(dict(metadata), "state_dict._metadata")  # type: ignore[attr-defined]
        return result
    return dict(items)


def save_checkpoint(path: str | os.PathLike, payload: dict[str, Any]) -> Path:
    """Write ``payload`` to ``path`` via a temporary file; the old file becomes ``<name>.prev``.
    Raises TypeError (and writes nothing) if the payload holds anything but plain data."""
    path = Path(path)
    data = plain({"format": FORMAT, **payload})
    with atomic_path(path) as tmp:
        torch.save(data, tmp)
        if path.exists():
            shutil.copy2(path, path.with_suffix(path.suffix + ".prev"))
    return path


def load_checkpoint(path: str | os.PathLike) -> dict[str, Any]:
    """Read a checkpoint written by :func:`save_checkpoint` with ``weights_only=True``; raise
    :class:`CheckpointError` for a missing, corrupt, unsafe or foreign file."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"checkpoint not found: {path}")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as exc:
        refused = _REFUSED_GLOBAL.search(str(exc))
        if refused:  # a pickle that names a Python object to build: never built here
            raise CheckpointError(
                f"checkpoint {path} refused: it needs the Python object {refused.group(1)} to load, and loading "
                f"it could run code; aslexp checkpoints ({FORMAT}) hold only tensors and plain data, so this "
                "file was written by an older aslexp or by something else: train again, or resume from a "
                "checkpoint this aslexp wrote") from None
        raise _corrupt(path, exc) from exc
    except Exception as exc:  # torch raises many types for truncated/garbled files
        raise _corrupt(path, exc) from exc
    if not isinstance(payload, dict) or payload.get("format") not in READABLE_FORMATS:
        raise CheckpointError(f"checkpoint {path} is not an {FORMAT} checkpoint")
    return payload


def _corrupt(path: Path, exc: Exception) -> CheckpointError:
    prev = path.with_suffix(path.suffix + ".prev")
    hint = f"; the previous checkpoint {prev} may still be good" if prev.is_file() else ""
    text = str(exc)
    if "WeightsUnpickler error:" in text:  # not torch's advice to load without weights_only
        text = text.split("WeightsUnpickler error:", 1)[1].split("Check the documentation", 1)[0]
    detail = " ".join(text.split())[:200]
    return CheckpointError(f"checkpoint {path} is corrupt or unreadable ({type(exc).__name__}: {detail}){hint}")
