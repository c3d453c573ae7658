"""Sweeps and extraction on a real Slurm cluster: a single-node cluster on loopback,
started by scripts/ci_slurm.sh. Recipe A (the launcher, trials in flight), recipe B (an array of
workers on one study), scancel of a running trial, and extraction as an array job."""

from __future__ import annotations

import json
import os
import shlex
import subprocess
import sys
import time
from datetime import datetime
from pathlib import Path

import optuna
import pytest
import job_process
from slurm_helpers import PROJECT_ROOT, accounting, require_cluster, wait_for_jobs
from sweep_helpers import run_cli, run_sweep, sweep_command

from aslexp.tuning.storage import open_storage
from aslexp.tuning.worker import ATTR_ERROR, ATTR_RUN_DIR, ATTR_STATE, INTERRUPTED

SHARED = PROJECT_ROOT.parent / "shared" / "data"
# A trial as a Slurm job: one core, little memory, minutes at most.
SLURM = ["hydra/launcher=slurm", "hydra.launcher.cpus_per_task=1", "hydra.launcher.mem_gb=1",
         "hydra.launcher.timeout_min=5", "hydra.launcher.partition=debug"]


@pytest.fixture(scope="module", autouse=True)
def cluster() -> None:
    require_cluster()


def _study(sweep: Path) -> optuna.Study:
    return optuna.load_study(study_name="quadratic", storage=open_storage(str(sweep / "optuna.journal")))


def _runs(study: optuna.Study, sweep: Path) -> dict[int, dict]:
    # Trial folders are recorded relative to the sweep folder.
    return {t.number: json.loads((sweep / t.user_attrs[ATTR_RUN_DIR] / "run.json").read_text())
            for t in study.trials if (sweep / t.user_attrs.get(ATTR_RUN_DIR, "/none") / "run.json").exists()}


def _overlap(rows: list[dict[str, str]]) -> bool:
    spans = sorted((datetime.fromisoformat(r["Start"]), datetime.fromisoformat(r["End"])) for r in rows)
    return any(later[0] < earlier[1] for earlier, later in zip(spans, spans[1:]))


def test_recipe_a_the_launcher_runs_each_trial_as_a_slurm_job_two_in_flight(tmp_path):
    sweep = tmp_path / "sweep"
    # 8 s per trial: Slurm starts a job submitted beside a running one 1-3 s later; with 3 s trials
    # the second could start just as the first ended, and "two in flight" was left to chance (CI).
    run_sweep(sweep, "hydra.sweeper.n_trials=4", "hydra.sweeper.n_workers=2", "sleep=8", *SLURM,
              timeout=300)
    study = _study(sweep)
    assert [t.state for t in study.trials] == [optuna.trial.TrialState.COMPLETE] * 4
    runs = _runs(study, sweep)
    jobs = [runs[n]["slurm"]["job_id"] for n in sorted(runs)]
    assert len(set(jobs)) == 4  # every trial was its own Slurm job
    for t in study.trials:
        assert runs[t.number]["status"] == "completed" and runs[t.number]["main_metric"]["value"] == t.value
    rows = accounting(jobs)
    assert {r["State"] for r in rows.values()} == {"COMPLETED"}
    assert _overlap(list(rows.values())), f"no two trials ran at once: {rows}"


def test_recipe_b_an_array_of_two_workers_shares_one_study(tmp_path):
    sweep = tmp_path / "sweep"
    command = sweep_command(sweep, "hydra.sweeper.n_trials=6", "sleep=1")  # one fixed sampler seed
    script = tmp_path / "sweep_worker.sbatch"
    script.write_text("#!/bin/bash\n"
                      f"#SBATCH --array=0-1 --cpus-per-task=1 --mem=1G --time=5 --output={tmp_path}/worker-%a.out\n"
                      f"cd {shlex.quote(str(tmp_path))}\n"
                      f"exec {shlex.join(command)}\n")
    job = subprocess.run(["sbatch", "--parsable", str(script)], capture_output=True, text=True,
                         check=True).stdout.strip()
    wait_for_jobs([job])
    rows = accounting([job], array_tasks=(0, 1))
    assert sorted(rows) == [f"{job}_0", f"{job}_1"]
    assert {r["State"] for r in rows.values()} == {"COMPLETED"}, rows
    study = _study(sweep)
    trials = study.trials
    assert len(trials) == 6 and all(t.state == optuna.trial.TrialState.COMPLETE for t in trials)
    points = [json.dumps(t.params, sort_keys=True) for t in trials]
    assert len(set(points)) == 6, f"duplicate points: {points}"  # both tasks started together
    tasks = {run["slurm"]["array_task_id"] for run in _runs(study, sweep).values()}
    assert tasks == {"0", "1"}  # both array tasks ran trials


def test_scancel_of_a_running_trial_interrupts_it_and_the_sweep_runs_a_replacement(tmp_path):
    sweep = tmp_path / "sweep"
    proc = subprocess.Popen(sweep_command(sweep, "hydra.sweeper.n_trials=2", "sleep=4", *SLURM),
                            cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    target = sweep / "1" / "run.json"  # trial 0 completes first: nothing else may be lost
    deadline = time.monotonic() + 120
    while not target.exists() and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.2)
    assert target.exists(), "trial 1 never started"
    before = {p: p.read_bytes() for p in (sweep / "0").rglob("*") if p.is_file()}
    job = json.loads(target.read_text())["slurm"]["job_id"]
    subprocess.run(["scancel", job], check=True)
    _, stderr = proc.communicate(timeout=240)
    assert proc.returncode == 0, stderr[-3000:]
    study = _study(sweep)
    states = {t.number: t.state for t in study.trials}
    assert states == {0: optuna.trial.TrialState.COMPLETE, 1: optuna.trial.TrialState.FAIL,
                      2: optuna.trial.TrialState.COMPLETE}  # 2: the replacement of 1
    cancelled = study.trials[1]
    assert cancelled.user_attrs[ATTR_STATE] == INTERRUPTED
    assert "CANCELLED" in cancelled.user_attrs[ATTR_ERROR]
    assert json.loads(target.read_text())["status"] == "interrupted"
    assert accounting([job])[job]["State"].startswith("CANCELLED")
    assert {p: p.read_bytes() for p in (sweep / "0").rglob("*") if p.is_file()} == before
    status = run_cli("sweep", "status", str(sweep)).stdout
    assert "budget 2, 2 counted, 0 to go" in status and "interrupted 1" in status


def _extract_has_shard() -> bool:
    out = job_process.run([sys.executable, "-m", "aslexp.cli", "extract", "--help"],
                         capture_output=True, text=True).stdout
    return "--shard" in out


@pytest.mark.skipif(not _extract_has_shard(), reason="needs aslexp extract --shard (ecosystem branch)")
def test_extraction_as_an_array_job_one_shard_per_task_resumable(tmp_path):
    """`aslexp extract --shard I/N`: task I of N takes the videos whose sorted index is I mod N,
    into one output folder and cache; submitting the array again recomputes nothing."""
    from aslexp.pose.extract import ExtractionError, mediapipe_python

    try:  # the array's tasks run MediaPipe: without its environment they fail, which tests nothing here
        mediapipe_python()
    except ExtractionError as err:
        if os.environ.get("CI"):
            raise
        pytest.skip(str(err))
    videos = tmp_path / "videos"
    videos.mkdir()
    for name in ("63185.mp4", "70212.mp4", "68011.mp4"):  # the three shortest clips
        os.symlink(SHARED / "videos" / "wlasl" / name, videos / name)
    out = tmp_path / "keypoints"
    script = tmp_path / "extract.sbatch"
    script.write_text("#!/bin/bash\n"
                      f"#SBATCH --array=0-1 --cpus-per-task=1 --mem=2G --time=10 --output={tmp_path}/extract-%a.out\n"
                      f"cd {shlex.quote(str(PROJECT_ROOT))}\n"
                      f"exec {shlex.quote(sys.executable)} -m aslexp.cli extract {shlex.quote(str(videos))} "
                      f"--out {shlex.quote(str(out))} --shard $SLURM_ARRAY_TASK_ID/2 --quiet\n")
    first = subprocess.run(["sbatch", "--parsable", str(script)], capture_output=True, text=True,
                           check=True).stdout.strip()
    wait_for_jobs([first], timeout=600)
    assert {r["State"] for r in accounting([first], array_tasks=(0, 1)).values()} == {"COMPLETED"}
    arrays = sorted(out.glob("*.npy"))
    assert [p.stem for p in arrays] == ["63185", "68011", "70212"]
    logs = [(tmp_path / f"extract-{i}.out").read_text() for i in (0, 1)]
    assert all(logs), "both tasks wrote a log"
    stamps = {p: p.stat().st_mtime_ns for p in arrays}
    again = subprocess.run(["sbatch", "--parsable", str(script)], capture_output=True, text=True,
                           check=True).stdout.strip()
    wait_for_jobs([again], timeout=600)
    assert {r["State"] for r in accounting([again], array_tasks=(0, 1)).values()} == {"COMPLETED"}
    assert {p: p.stat().st_mtime_ns for p in arrays} == stamps  # resumed: nothing recomputed


def test_recipe_a_a_trial_whose_sweep_was_killed_is_waited_for_and_adopted(tmp_path):
    """SIGKILL of the sweep process (recipe A: it waits for its trial's Slurm job) leaves the job
    running; the same command resumes, waits for the job and adopts the result its run.json
    records: no replacement, and study, run.json and `sweep status` agree."""
    sweep = tmp_path / "sweep"
    command = ["hydra.sweeper.n_trials=1", "sleep=10", *SLURM]
    with open(tmp_path / "sweep.err", "w") as err:  # a file: the job does not inherit it
        proc = subprocess.Popen(sweep_command(sweep, *command), cwd=tmp_path,
                                stdout=subprocess.DEVNULL, stderr=err)
    target = sweep / "0" / "run.json"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        if target.exists() and json.loads(target.read_text())["status"] == "running":
            break
        time.sleep(0.2)
    job = json.loads(target.read_text())["slurm"]["job_id"]
    proc.kill()
    proc.wait()
    resumed = run_sweep(sweep, *command, timeout=240)
    log = resumed.stdout + resumed.stderr
    assert "waiting for trial 0 to adopt its result" in log and f"Slurm job {job}" in log
    study = _study(sweep)
    assert [t.state for t in study.trials] == [optuna.trial.TrialState.COMPLETE]
    run = json.loads(target.read_text())
    assert run["status"] == "completed" and run["main_metric"]["value"] == study.trials[0].value
    assert "result adopted from" in study.trials[0].user_attrs["aslexp_adopted"]
    assert sorted(p.name for p in sweep.iterdir() if p.is_dir() and not p.name.startswith(".")) == ["0"]
    assert accounting([job])[job]["State"] == "COMPLETED"
    status = run_cli("sweep", "status", str(sweep)).stdout
    assert "budget 1, 1 counted, 0 to go" in status and "complete 1" in status


def _largest_node_gb() -> int:
    out = subprocess.run(["sinfo", "-h", "-p", "debug", "-o", "%m"], capture_output=True, text=True, check=True)
    return max(int(v.rstrip("+")) for v in out.stdout.split()) // 1024


def _queued_jobs(name: str) -> list[str]:
    return subprocess.run(["squeue", "-h", "-n", name, "-o", "%i"], capture_output=True, text=True).stdout.split()


def test_a_memory_request_above_every_node_is_refused_in_one_line_and_the_study_resumes(tmp_path):
    """The launcher's default of 32 GB on a smaller node: one line naming hydra.launcher.mem_gb and
    the size that fits, exit 2, nothing submitted, and the trial not counted; the same command with
    that size then runs the whole budget."""
    sweep = tmp_path / "sweep"
    largest = _largest_node_gb()
    too_much = [*SLURM, f"hydra.launcher.mem_gb={largest + 64}"]
    refused = run_sweep(sweep, "hydra.sweeper.n_trials=2", *too_much, check=False, timeout=120)
    lines = [ln for ln in refused.stderr.splitlines() if ln.strip() and not ln.startswith("[20")]
    assert refused.returncode == 2, refused.stderr[-3000:]
    assert len(lines) == 1, lines
    assert lines[0].startswith(f"aslexp quadratic: hydra.launcher.mem_gb={largest + 64}: Slurm cannot give a job "
                               f"{largest + 64} GB on partition 'debug'; the largest node of partition 'debug' has ")
    assert lines[0].endswith(f"MB: set hydra.launcher.mem_gb={largest} or less (null: Slurm's default); "
                             "nothing was submitted")  # fmt: skip
    assert not _queued_jobs("quadratic") and not list(sweep.rglob("*.submission_file*"))
    study = _study(sweep)
    assert [t.user_attrs.get(ATTR_STATE) for t in study.trials] == [INTERRUPTED]  # not counted: run again
    run_sweep(sweep, "hydra.sweeper.n_trials=2", *SLURM, f"hydra.launcher.mem_gb={largest}", timeout=300)
    study = _study(sweep)
    assert sum(t.state == optuna.trial.TrialState.COMPLETE for t in study.trials) == 2


def test_a_plain_multirun_with_too_much_memory_stops_in_one_line(tmp_path):
    """The same refusal without the Optuna sweeper (a grid over the basic sweeper)."""
    sweep = tmp_path / "grid"
    largest = _largest_node_gb()
    proc = job_process.run([sys.executable, "-m", "aslexp.jobs.quadratic", "-m", "x=0.5,1.5",
                            f"hydra.sweep.dir={sweep}", *SLURM, f"hydra.launcher.mem_gb={largest + 64}"],
                           cwd=tmp_path, capture_output=True, text=True, timeout=120,
                           env={**os.environ, "HYDRA_FULL_ERROR": "0"})  # fmt: skip
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip() and not ln.startswith("[20")]
    assert proc.returncode == 2, proc.stderr[-3000:]
    assert len(lines) == 1 and f"hydra.launcher.mem_gb={largest + 64}: Slurm cannot give a job" in lines[0], lines
    assert f"set hydra.launcher.mem_gb={largest} or less" in lines[0] and "Traceback" not in proc.stderr
    assert not _queued_jobs("quadratic")
