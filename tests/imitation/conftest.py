"""Shared fixtures of the imitation tests: the real data root and small real motions."""

from __future__ import annotations

from pathlib import Path

import pytest

from aslexp.data.root import resolve_data_root


@pytest.fixture(scope="session")
def data_root() -> Path:
    root = resolve_data_root(None, must_exist=False)
    if not (root / "motions" / "hand" / "A.txt").is_file():
        pytest.skip(f"thesis motions not found under {root}")
    return root


@pytest.fixture(scope="session")
def motion_a(data_root) -> Path:
    return data_root / "motions" / "hand" / "A.txt"
