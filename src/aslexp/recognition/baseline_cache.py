"""Simple baselines measured once per data, split and setting, then reused.

A sweep over a model's hyperparameters, or a multirun over models, fits the same simple baselines
(``simple_baseline``: logreg and rf by default) on the same splits with the same seeds in every run:
in a tiny run they are about half its time. Their results depend only on what is hashed here (the
arrays and labels of the dataset and of every split, the folds, the baseline's name and parameters,
the trainer settings, the seeds, the versions of the code that fits and scores them), so a run
reads them from ``<cache_dir>/simple_baselines/`` when another run measured them, and the numbers
are the same as measured again (each fit is seeded; JSON keeps every float exactly).
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import logging
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from aslexp.files import atomic_write_text

log = logging.getLogger(__name__)

FORMAT = "aslexp.simple_baselines/1"
# The code whose change changes a baseline's numbers: its source is part of the key.
_CODE = ("models/classical.py", "train.py", "metrics.py", "experiment.py")


@functools.cache  # the source read once per process, not once per baseline and split
def _code_digest() -> str:
    import sklearn

    digest = hashlib.sha256(sklearn.__version__.encode())
    here = Path(__file__).resolve().parent
    for name in _CODE:
        digest.update((here / name).read_bytes())
    return digest.hexdigest()


def data_digest(arrays: Sequence[np.ndarray]) -> str:
    """The hash of a split's arrays (computed once per split, shared by its baselines)."""
    digest = hashlib.sha256()
    for array in arrays:
        array = np.ascontiguousarray(array)
        digest.update(f"{array.dtype}{array.shape}".encode())
        digest.update(array.tobytes())
    return digest.hexdigest()


def cache_key(name: str, params: dict[str, Any], config: Any, seeds: Sequence[int], label_names: Sequence[str],
              data: str) -> str:
    """The hash of everything a simple baseline's results depend on (``data``: :func:`data_digest`)."""
    digest = hashlib.sha256(FORMAT.encode())
    settings = dataclasses.asdict(config) if dataclasses.is_dataclass(config) else dict(config)
    digest.update(json.dumps({"name": name, "params": params, "config": settings, "seeds": [int(s) for s in seeds],
                              "labels": [str(x) for x in label_names], "data": data},
                             sort_keys=True, default=str).encode())
    digest.update(_code_digest().encode())
    return digest.hexdigest()


def cached(folder: str | Path | None, key: str, name: str,
           measure: Callable[[], tuple[list[dict], list[dict]]]) -> tuple[list[dict], list[dict], bool]:
    """(validation records, test metrics, read from the cache) for ``key``: the stored file's, else
    ``measure()``'s, stored for the next run. No folder: always measured. A damaged file is measured
    again and replaced (one warning line)."""
    if folder is None:
        val, tests = measure()
        return val, tests, False  # as measured: no cache, nothing to compare with
    path = Path(folder) / f"{name}-{key[:24]}.json"
    if path.is_file():
        try:
            stored = json.loads(path.read_text(encoding="utf-8"))
            if stored.get("format") == FORMAT and stored.get("key") == key:
                return stored["val"], stored["tests"], True
            log.warning("warning: %s: not a simple-baseline record of this key; measured again", path)
        except (OSError, ValueError, KeyError, AttributeError) as error:
            log.warning("warning: %s: unreadable (%s); measured again", path, error)
    # Measured results pass through JSON too: a run that measured them and one that read them carry
    # the same Python numbers.
    val, tests = measure()
    text = json.dumps({"format": FORMAT, "key": key, "val": val, "tests": tests}, default=_plain)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(path, text)
    except OSError as error:  # a cache that cannot be written costs the next run time, never this run
        log.warning("warning: %s: not written (%s); the next run measures again", path, error)
    stored = json.loads(text)
    return stored["val"], stored["tests"], False


def _plain(value: Any) -> Any:
    """numpy scalars and arrays as JSON numbers and lists."""
    if hasattr(value, "tolist"):
        return value.tolist()
    raise TypeError(f"{type(value).__name__} is not JSON serialisable")
