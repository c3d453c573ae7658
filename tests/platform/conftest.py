"""Fixtures for end-to-end tests of the platform: real CLI, real Hydra, real data."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
import job_process

PROJECT_ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="session")
def cache_dir(tmp_path_factory) -> Path:
    """One WLASL-Lex cache for the whole session, so each build happens once."""
    return tmp_path_factory.mktemp("cache")


@pytest.fixture(scope="session")  # a stateless runner: module fixtures run their jobs with it too
def aslexp(cache_dir):
    """Run `aslexp ARGS...` in a subprocess from the project root; returns CompletedProcess."""

    def run(*args: str, check: bool = True, timeout: float = 300) -> subprocess.CompletedProcess:
        env = dict(os.environ, ASLEXP_CACHE_DIR=str(cache_dir), MPLBACKEND="Agg")
        proc = job_process.run(
            [sys.executable, "-m", "aslexp.cli", *args], cwd=PROJECT_ROOT, env=env,
            capture_output=True, text=True, timeout=timeout,
        )
        if check and proc.returncode != 0:
            raise AssertionError(
                f"aslexp {' '.join(args)} exited {proc.returncode}\n--- stdout\n{proc.stdout[-3000:]}"
                f"\n--- stderr\n{proc.stderr[-5000:]}"
            )
        return proc

    return run
