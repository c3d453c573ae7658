"""Fixtures for the recognition tests (data helpers live in recognition_data.py)."""

from __future__ import annotations

import pytest
from recognition_data import load_gloss_dataset

from aslexp.data.dataset import RecognitionDataset


@pytest.fixture(scope="session")
def gloss_dataset() -> RecognitionDataset:
    return load_gloss_dataset()


@pytest.fixture(autouse=True)
def _one_thread():
    """The machine's 2 cores are shared: tests train on one thread."""
    import torch

    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)
