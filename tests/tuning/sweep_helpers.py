"""Helpers for the sweep tests: run the quadratic job as a real Hydra multirun in a subprocess."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import optuna
import job_process

PG_URL_DEFAULT = "postgresql://aslexp:aslexp@127.0.0.1:5432/aslexp_test"


def sweep_command(sweep_dir: Path, *overrides: str, overlay: str = "quadratic") -> list[str]:
    return [sys.executable, "-m", "aslexp.jobs.quadratic", "-m", f"+sweeps={overlay}",
            f"hydra.sweep.dir={sweep_dir}", "hydra.sweeper.sampler.seed=7", *overrides]


def run_sweep(sweep_dir: Path, *overrides: str, overlay: str = "quadratic", check: bool = True,
              timeout: float = 120, env: dict | None = None) -> subprocess.CompletedProcess:
    """The sweep as a process of its own; ``env``: variables added to this one's environment."""
    result = job_process.run(sweep_command(sweep_dir, *overrides, overlay=overlay),
                            cwd=sweep_dir.parent, capture_output=True, text=True, timeout=timeout,
                            env={**os.environ, "HYDRA_FULL_ERROR": "0", **(env or {})})
    if check and result.returncode != 0:
        raise AssertionError(f"sweep failed ({result.returncode}):\n{result.stdout}\n{result.stderr}")
    return result


def load_study(sweep_dir: Path, storage: str | None = None, name: str = "quadratic") -> optuna.Study:
    from aslexp.tuning.storage import open_storage

    spec = storage or str(sweep_dir / "optuna.journal")
    return optuna.load_study(study_name=name, storage=open_storage(spec))


def postgres_url() -> str | None:
    """The test database URL if a PostgreSQL server answers there, else None."""
    url = os.environ.get("ASLEXP_TEST_POSTGRES_URL", PG_URL_DEFAULT)
    try:
        import sqlalchemy

        engine = sqlalchemy.create_engine(url, poolclass=sqlalchemy.pool.NullPool,
                                          connect_args={"connect_timeout": 3})
        with engine.connect() as conn:
            conn.execute(sqlalchemy.text("SELECT 1"))
        return url
    except Exception:  # noqa: BLE001 - any failure means: no server to test against
        return None


def run_cli(*args: str, cwd: Path | None = None, check: bool = True) -> subprocess.CompletedProcess:
    """``python -m aslexp.runs.cli ...`` (what ``aslexp runs|sweep ...`` dispatches to)."""
    return job_process.run([sys.executable, "-m", "aslexp.runs.cli", *args], cwd=cwd,
                          capture_output=True, text=True, check=check, timeout=120)


def wait_for(predicate, timeout: float, what: str) -> None:
    """Poll ``predicate`` every 0.1 s; fail naming ``what`` after ``timeout`` seconds."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return
        time.sleep(0.1)
    raise AssertionError(f"timed out waiting for {what}")
