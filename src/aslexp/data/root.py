"""Where the data lives: one setting, resolved the same way everywhere."""

from __future__ import annotations

import os
from pathlib import Path

ENV_VAR = "ASLEXP_DATA_ROOT"
DEFAULT_ROOT = "../shared/data"

# src/aslexp/data/root.py -> the project root is three levels up from this folder.
PROJECT_ROOT = Path(__file__).resolve().parents[3]


def resolve_data_root(root: str | os.PathLike | None = None, must_exist: bool = True) -> Path:
    """Resolve the data root.

    Order: the explicit ``root`` argument, then ``$ASLEXP_DATA_ROOT``, then ``../shared/data``.
    A relative path is taken against the current directory first and then against the project
    root, so ``../shared/data`` works from the checkout and from inside a Hydra run directory.
    """
    raw = str(root) if root not in (None, "") else os.environ.get(ENV_VAR) or DEFAULT_ROOT
    path = Path(raw).expanduser()
    candidates = [path] if path.is_absolute() else [Path.cwd() / path, PROJECT_ROOT / path]
    for candidate in candidates:
        if candidate.is_dir():
            return candidate.resolve()
    if must_exist:
        tried = ", ".join(str(c) for c in candidates)
        raise FileNotFoundError(
            f"data root {raw!r} not found (tried {tried}); set data.root=DIR or ${ENV_VAR}, "
            f"or fetch the public files with `aslexp data fetch --root DIR`"
        )
    return candidates[-1]
