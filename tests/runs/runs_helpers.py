"""Helpers of the runs/sweep tool tests."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path
import job_process


def run_cli(*args: str, cwd: Path | None = None, check: bool = True) -> subprocess.CompletedProcess:
    """``python -m aslexp.runs.cli ...`` (what ``aslexp runs|sweep ...`` dispatches to)."""
    return job_process.run([sys.executable, "-m", "aslexp.runs.cli", *args], cwd=cwd,
                          capture_output=True, text=True, check=check, timeout=120)
