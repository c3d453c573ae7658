"""Shared fixtures: the real data root and the parsed annotation files (read once per session)."""

from __future__ import annotations

import pytest

from aslexp.data.lexicon import load_lexicon
from aslexp.data.root import resolve_data_root
from aslexp.data.wlasl import load_wlasl


@pytest.fixture(scope="session")
def data_root():
    try:
        return resolve_data_root()
    except FileNotFoundError as error:
        pytest.skip(f"real data not available: {error}")


@pytest.fixture(scope="session")
def wlasl(data_root):
    return load_wlasl(data_root)


@pytest.fixture(scope="session")
def lexicons(data_root):
    return {name: load_lexicon(name, data_root) for name in ("asllex1", "asllex2")}
