"""Fixtures for the recognition tests (data helpers live in recognition_data.py)."""

from __future__ import annotations

import pytest
import job_process
from recognition_data import load_gloss_dataset, load_lex_dataset

from aslexp.data.dataset import RecognitionDataset


@pytest.fixture(scope="session")
def gloss_dataset() -> RecognitionDataset:
    return load_gloss_dataset()


@pytest.fixture(scope="session")
def lex_dataset() -> RecognitionDataset:
    """The real WLASL-Lex sign-type set (ASL-LEX 2.0, 283 clips, 5 classes) at T = 24 frames."""
    return load_lex_dataset()


@pytest.fixture(autouse=True)
def _one_thread():
    """The machine's 2 cores are shared: tests train on one thread."""
    import torch

    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)


@pytest.fixture()
def run_cli(tmp_path_factory):
    """`python -m aslexp.cli ARGS...` from the project root with its own dataset cache."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    env = dict(os.environ, ASLEXP_CACHE_DIR=str(tmp_path_factory.getbasetemp() / "cli-cache"), MPLBACKEND="Agg")

    def run(*args: str, timeout: float = 600) -> subprocess.CompletedProcess:
        proc = job_process.run([sys.executable, "-m", "aslexp.cli", *args], cwd=root, env=env, capture_output=True,
                              text=True, timeout=timeout)  # fmt: skip
        assert proc.returncode == 0, f"aslexp {' '.join(args)} exited {proc.returncode}\n{proc.stderr[-4000:]}"
        return proc

    return run
