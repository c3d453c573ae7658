"""A small real sweep of the quadratic job, shared by the runs/sweep tool tests."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
import job_process


@pytest.fixture(scope="session")
def small_sweep(tmp_path_factory) -> Path:
    """5 trials with 3 reported steps each; points with x > 0.6 fail."""
    root = tmp_path_factory.mktemp("runs")
    sweep = root / "sweep"
    job_process.run([sys.executable, "-m", "aslexp.jobs.quadratic", "-m", "+sweeps=quadratic",
                    f"hydra.sweep.dir={sweep}", "hydra.sweeper.n_trials=5",
                    "hydra/sweeper/sampler=random", "hydra.sweeper.sampler.seed=3", "steps=3",
                    "fail_if='x > 0.6'", "seed=11"],
                   cwd=root, check=True, capture_output=True, timeout=120)
    return sweep
