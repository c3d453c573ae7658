"""A real Slurm cluster for the sweep tests: found, or started with scripts/ci_slurm.sh (as root).

Without root, and with no cluster answering, the Slurm tests skip and say why; under
``CI=true`` a cluster that cannot start is a failure, never a skip.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import time
from pathlib import Path

import pytest

PROJECT_ROOT = Path(__file__).resolve().parents[2]
CI_SCRIPT = PROJECT_ROOT / "scripts" / "ci_slurm.sh"


def cluster_answers() -> bool:
    if shutil.which("sinfo") is None or shutil.which("sbatch") is None:
        return False
    try:
        out = subprocess.run(["sinfo", "-h", "-N", "-o", "%T"], capture_output=True, text=True,
                             timeout=10).stdout.split()
    except (OSError, subprocess.SubprocessError):
        return False
    return any(state.rstrip("*") in ("idle", "mixed", "allocated") for state in out)


def require_cluster() -> None:
    """Return when a Slurm cluster answers; otherwise start one (root) or skip/fail."""
    if cluster_answers():
        return
    in_ci = os.environ.get("CI", "").lower() == "true"
    if os.geteuid() != 0:
        reason = ("no Slurm cluster answers and starting the loopback one needs root: "
                  f"sudo bash {CI_SCRIPT}")
        pytest.fail(reason) if in_ci else pytest.skip(reason)
    proc = subprocess.run(["bash", str(CI_SCRIPT)], capture_output=True, text=True, timeout=900)
    if proc.returncode != 0 or not cluster_answers():
        reason = f"scripts/ci_slurm.sh could not start Slurm:\n{proc.stdout[-2000:]}\n{proc.stderr[-2000:]}"
        pytest.fail(reason) if in_ci else pytest.skip(reason)


def wait_for_jobs(job_ids: list[str], timeout: float = 180) -> None:
    """Poll squeue until none of ``job_ids`` (array ids included) is pending or running."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        out = subprocess.run(["squeue", "-h", "-o", "%i", "-j", ",".join(job_ids)],
                             capture_output=True, text=True).stdout.split()
        if not out:
            return
        time.sleep(0.5)
    raise AssertionError(f"Slurm jobs {job_ids} still queued after {timeout} s")


def accounting(job_ids: list[str], array_tasks: tuple[int, ...] = (),
               timeout: float = 60) -> dict[str, dict[str, str]]:
    """``sacct`` rows (allocations only) by job id: State, Start, End.

    slurmdbd records asynchronously: squeue can be empty while sacct still lacks a row or shows it
    unfinished (CI once saw task 1 of an array and not task 0). So poll until every expected row
    (each job id, or ``<id>_<task>`` for each of ``array_tasks``) is there and has ended; after
    ``timeout`` return what sacct has, for the caller's assertion to show."""
    expected = ({f"{j}_{t}" for j in job_ids for t in array_tasks} if array_tasks
                else set(job_ids))
    deadline = time.monotonic() + timeout
    while True:
        out = subprocess.run(["sacct", "-X", "-n", "-P", "-o", "JobID,State,Start,End", "-j",
                              ",".join(job_ids)], capture_output=True, text=True, check=True).stdout
        rows = {}
        for line in out.splitlines():
            job, state, start, end = line.split("|")
            rows[job] = {"State": state, "Start": start, "End": end}
        settled = expected <= rows.keys() and all(
            rows[j]["End"] not in ("", "Unknown") and rows[j]["State"] not in _UNFINISHED
            for j in expected)
        if settled or time.monotonic() > deadline:
            return rows
        time.sleep(0.5)


_UNFINISHED = {"PENDING", "RUNNING", "REQUEUED", "RESIZING", "SUSPENDED", "COMPLETING"}
