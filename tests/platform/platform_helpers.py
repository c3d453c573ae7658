"""Helpers of the platform tests: folder fingerprints and the quadratic job as a subprocess."""

from __future__ import annotations

import hashlib
import os
import subprocess
import sys
from pathlib import Path
import job_process


def folder_hashes(folder: Path) -> dict[str, str]:
    """``{relative path: sha256}`` of every file under ``folder`` (hidden ones included)."""
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def quadratic(*overrides: str, cwd: Path, check: bool = True, env: dict | None = None,
              timeout: float = 120) -> subprocess.CompletedProcess:
    """``python -m aslexp.jobs.quadratic OVERRIDES`` (the sweep machinery's test job)."""
    proc = job_process.run([sys.executable, "-m", "aslexp.jobs.quadratic", *overrides], cwd=cwd,
                          capture_output=True, text=True, timeout=timeout,
                          env={**os.environ, **(env or {})})
    if check and proc.returncode != 0:
        raise AssertionError(f"quadratic {overrides} exited {proc.returncode}:\n{proc.stderr[-3000:]}")
    return proc


def error_lines(stderr: str) -> list[str]:
    """stderr without the job's own log lines (timestamped) and blank lines."""
    return [ln for ln in stderr.splitlines() if ln.strip() and not ln.startswith("[20")]
