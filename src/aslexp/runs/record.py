"""A run is a folder: what every job writes about itself, and nothing Hydra-specific.

Layout of a run directory (the jobs fill it; tools under ``aslexp.runs`` only read it):

    .hydra/            resolved config, hydra config, overrides (written by Hydra)
    run.json           job, command line, git commit and dirty flag, seed, host, versions,
                       the process (host, pid, start; Slurm job when there is one),
                       start/end time, status (running|completed|failed|pruned|interrupted),
                       error (one line) and traceback, main metric; in a sweep, the trial
                       (study, number, the sampler's settings)
    metrics.json       the job's numbers (the main metric among them)
    <job>.log          the log
    ...                plots (PNG), tables (CSV), checkpoints
"""

from __future__ import annotations

import functools
import math
import os
import platform
import shlex
import socket
import subprocess
import sys
import traceback
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Any

from aslexp.files import read_json, write_json
from aslexp.process import process_identity, slurm_context
from aslexp.runfile import RUN_FILE, timestamp

METRICS_FILE = "metrics.json"

_TRACKED_PACKAGES = (
    "aslexp", "torch", "numpy", "hydra-core", "omegaconf", "optuna", "scikit-learn",
    "pybullet", "gymnasium", "torchrl", "tensordict", "mujoco",
)


class RunExistsError(RuntimeError):
    """Raised when a job would overwrite a finished run."""


def finished_run(run_dir: str | os.PathLike) -> dict[str, Any] | None:
    """The run.json of ``run_dir`` if it records a finished (completed) run, else None."""
    path = Path(run_dir) / RUN_FILE
    if not path.is_file():
        return None
    try:
        info = read_json(path)
    except (OSError, ValueError):
        return None
    return info if isinstance(info, dict) and info.get("status") == "completed" else None


def refuse_finished_run(run_dir: str | os.PathLike) -> None:
    """Raise :class:`RunExistsError` if ``run_dir`` holds a finished run (nothing is changed)."""
    previous = finished_run(run_dir)
    if previous is not None:
        metric = previous.get("main_metric") or {}
        shown = f", {metric.get('name')}={metric.get('value')}" if metric.get("name") else ""
        raise RunExistsError(
            f"{run_dir} holds a finished run ({previous.get('job')}, finished "
            f"{previous.get('finished')}{shown}); nothing was changed: choose another "
            "hydra.run.dir, or add overwrite=true to replace it"
        )


LOCK_FILE = ".aslexp-run.lock"  # held (flock) by the one process running in the folder
_held_locks: dict[str, Any] = {}  # run folder -> open lock file, kept for the process' lifetime


class RunFolderBusy(RunExistsError):
    """Another live process runs in this folder."""


def claim_new_folder(run_dir: str | os.PathLike) -> Path:
    """Create ``run_dir`` exclusively; if it exists, ``<name>_2``, ``<name>_3``, ... (the first
    free one). Jobs started in the same second with the same default name never share a folder."""
    base = Path(run_dir)
    base.parent.mkdir(parents=True, exist_ok=True)
    candidate, k = base, 1
    while True:
        try:
            candidate.mkdir(exist_ok=False)
            return candidate
        except FileExistsError:
            k += 1
            candidate = base.with_name(f"{base.name}_{k}")


def hold_run_folder(run_dir: str | os.PathLike) -> None:
    """Take the folder's run lock for the rest of this process (the kernel drops it on exit).

    Raises :class:`RunFolderBusy`, naming the holder, if another live process holds it: two jobs
    (two resumes of one run, two array tasks given one ``hydra.run.dir``) never share a folder.
    """
    import fcntl

    folder = Path(run_dir)
    key = str(folder.resolve())
    if key in _held_locks:
        return
    folder.mkdir(parents=True, exist_ok=True)
    handle = open(folder / LOCK_FILE, "a+", encoding="utf-8")
    try:
        fcntl.flock(handle.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        handle.seek(0)
        holder = handle.read().strip() or "another process"
        handle.close()
        raise RunFolderBusy(
            f"{folder} is in use by another aslexp job ({holder}); nothing was changed: wait for "
            "it, or choose another hydra.run.dir"
        ) from None
    handle.seek(0)
    handle.truncate()
    handle.write(f"pid {os.getpid()} on {socket.gethostname()} since {timestamp()}\n")
    handle.flush()
    _held_locks[key] = handle


def git_state(cwd: str | os.PathLike | None = None) -> dict[str, Any]:
    """Commit and dirty flag of the checkout the code runs from (None outside git)."""
    where = Path(cwd) if cwd else Path(__file__).resolve().parent
    try:
        commit = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=where, capture_output=True, text=True, timeout=10
        )
        if commit.returncode != 0:
            return {"commit": None, "dirty": None}
        status = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=where, capture_output=True, text=True, timeout=10,
        )
        return {"commit": commit.stdout.strip(), "dirty": bool(status.stdout.strip())}
    except (OSError, subprocess.SubprocessError):
        return {"commit": None, "dirty": None}


@functools.lru_cache(maxsize=1)
def library_versions() -> dict[str, str | None]:
    versions: dict[str, str | None] = {"python": platform.python_version()}
    for name in _TRACKED_PACKAGES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = None
    return versions


def command_line(argv: list[str] | None = None) -> str:
    argv = list(sys.argv if argv is None else argv)
    if argv and argv[0].endswith(("aslexp", "__main__.py")):
        argv[0] = "aslexp"
    return shlex.join(argv)


@dataclass
class Run:
    """Handle on a run directory; created by :func:`start_run`."""

    dir: Path
    info: dict[str, Any] = field(default_factory=dict)

    def path(self, name: str) -> Path:
        return self.dir / name

    def _save(self) -> None:
        write_json(self.dir / RUN_FILE, self.info)

    def set_main_metric(self, name: str, value: float, goal: str = "maximize") -> None:
        self.info["main_metric"] = {"name": name, "value": value, "goal": goal}
        self._save()

    def save_metrics(self, metrics: dict[str, Any]) -> None:
        write_json(self.dir / METRICS_FILE, metrics)

    def finish(self, status: str = "completed", error: str | None = None,
               traceback_text: str | None = None) -> None:
        self.info["status"] = status
        self.info["finished"] = timestamp()
        if error is not None:
            self.info["error"] = error
        if traceback_text is not None:
            self.info["traceback"] = traceback_text
        self._save()

    def __enter__(self) -> "Run":
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        if exc is None:
            self.finish("completed")
        elif isinstance(exc, KeyboardInterrupt):
            self.finish("interrupted", "KeyboardInterrupt")
        elif type(exc).__name__ == "TrialPruned":  # optuna's: a sweep stopped it early, by design
            self.finish("pruned", str(exc))
        else:
            self.finish("failed", "".join(traceback.format_exception_only(exc_type, exc)).strip(),
                        "".join(traceback.format_exception(exc_type, exc, tb)))
        return False


def start_run(
    run_dir: str | os.PathLike,
    job: str,
    seed: int | None = None,
    overwrite: bool = False,
    extra: dict[str, Any] | None = None,
) -> Run:
    """Record the start of a run in ``run_dir``; refuse to overwrite a finished run.

    (The jobs refuse earlier, before Hydra writes anything: see ``aslexp.jobs._common``.)
    """
    run_dir = Path(run_dir)
    if not overwrite:
        refuse_finished_run(run_dir)
    from aslexp.tuning.context import current_trial_context, refuse_given_up_trial

    if (run_dir / RUN_FILE).exists():  # a sweep's trial started again (a requeued Slurm job)
        refuse_given_up_trial()  # given up in the study: its record there stays as the study has it
    trial = current_trial_context()
    run_dir.mkdir(parents=True, exist_ok=True)
    info: dict[str, Any] = {
        "job": job,
        "command": command_line(),
        "cwd": os.getcwd(),
        "git": git_state(),
        "seed": seed,
        "host": socket.gethostname(),
        "process": process_identity(),
        "slurm": slurm_context(),
        "platform": platform.platform(),
        "versions": dict(library_versions()),
        "started": timestamp(),
        "finished": None,
        "status": "running",
        "error": None,
        "main_metric": None,
    }
    if trial is not None:  # a sweep's trial: which one, and every setting of the sampler that drew it
        info["trial"] = {"study_name": trial.study_name, "number": trial.number, "sampler": dict(trial.sampler or {})}
    if extra:
        info.update(extra)
    run = Run(run_dir, info)
    run._save()
    return run


def is_finite(value: Any) -> bool:
    try:
        return math.isfinite(float(value))
    except (TypeError, ValueError):
        return False
