"""A trial whose job outlives its sweep process is adopted, not replaced.

With ``hydra/launcher=local`` (submitit's local executor) or Slurm recipe A each trial's job is a
process of its own: killing the sweep leaves it running. The resume waits for it and tells the
study the result its run.json records; no replacement runs, and study, run.json and
``sweep status`` agree. Real sweeps of the quadratic job, real processes, real journal files.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import optuna
import pytest
import job_process
from optuna.trial import TrialState
from sweep_helpers import load_study, run_cli, run_sweep, sweep_command, wait_for

from aslexp.process import process_identity, process_is_gone
from aslexp.tuning.storage import open_storage
from aslexp.tuning.worker import (
    ATTR_ADOPTED,
    ATTR_ERROR,
    ATTR_HEARTBEAT,
    ATTR_RUN_DIR,
    ATTR_STATE,
    ATTR_WORKER,
    INTERRUPTED,
    judge_running_trial,
    settle_stale_trials,
)

LOCAL = ["hydra/launcher=local"]


def _run(folder: Path) -> dict | None:
    try:
        return json.loads((folder / "run.json").read_text())
    except (OSError, ValueError):
        return None


def _status_is(folder: Path, status: str) -> bool:
    return (_run(folder) or {}).get("status") == status


def _start(sweep: Path, *overrides: str) -> subprocess.Popen:
    """The sweep in a session of its own: the test signals the sweep process alone, as
    ``kill PID`` does (its trial's job, a child process, does not get the signal). Its stderr
    goes to a file: the job inherits it, so a pipe would stay open as long as the job runs."""
    with open(sweep.parent / "sweep.err", "w") as err:
        return subprocess.Popen(sweep_command(sweep, *overrides), cwd=sweep.parent,
                                stdout=subprocess.DEVNULL, stderr=err, start_new_session=True)


def _trial_folders(sweep: Path) -> list[str]:
    return sorted(p.name for p in sweep.iterdir() if p.is_dir() and not p.name.startswith("."))


def _assert_one_story(sweep: Path, budget: int, adopted: int) -> optuna.Study:
    """Study, run folders and `sweep status` agree: every trial complete with its run.json's
    value, the orphan adopted, no replacement (as many trials and folders as the budget)."""
    study = load_study(sweep)
    trials = study.trials
    assert [t.state for t in trials] == [TrialState.COMPLETE] * budget
    assert _trial_folders(sweep) == [str(n) for n in range(budget)]
    for t in trials:
        run = _run(sweep / str(t.number))
        assert run["status"] == "completed" and run["main_metric"]["value"] == t.value
    orphan = trials[adopted]
    assert "result adopted from" in orphan.user_attrs[ATTR_ADOPTED]
    assert ATTR_ERROR not in orphan.user_attrs
    status = json.loads(run_cli("sweep", "status", str(sweep), "--json").stdout)
    assert status["counts"] == {"complete": budget} and status["trials"] == budget
    assert status["lost"] == status["orphans_running"] == status["orphans_finished"] == 0
    assert status["adopted"] == [adopted]
    text = run_cli("sweep", "status", str(sweep)).stdout
    assert f"(budget {budget}, {budget} counted, 0 to go)" in text and f"complete {budget}" in text
    return study


def test_a_job_that_finished_after_its_sweep_was_killed_is_adopted_on_resume(tmp_path):
    sweep = tmp_path / "sweep"
    # 8 s: `sweep status` below must find the job still running (3 s was too short where the status
    # command itself took seconds to start: a busy machine, the first job of a test process)
    command = [*LOCAL, "hydra.sweeper.n_trials=2", "sleep=8"]
    proc = _start(sweep, *command)
    wait_for(lambda: _status_is(sweep / "0", "running"), 30, "trial 0's job running")
    proc.kill()  # SIGKILL, the sweep process only
    proc.wait()
    job = _run(sweep / "0")["process"]
    assert job["pid"] != proc.pid and not process_is_gone(job)  # the job goes on alone
    text = run_cli("sweep", "status", str(sweep)).stdout
    assert "running 1" in text and "their jobs still run: the resume waits for them" in text

    wait_for(lambda: _status_is(sweep / "0", "completed"), 30, "the orphaned job to complete")
    finished = (sweep / "0" / "run.json").read_bytes()
    text = run_cli("sweep", "status", str(sweep)).stdout
    assert "running 1" in text and "their jobs finished: the resume adopts their results" in text

    resumed = run_sweep(sweep, *command)  # the same command
    log = resumed.stdout + resumed.stderr
    assert "trial 0 complete (value" in log and "result adopted from" in log
    study = _assert_one_story(sweep, budget=2, adopted=0)
    assert study.trials[0].value == json.loads(finished)["main_metric"]["value"]
    assert (sweep / "0" / "run.json").read_bytes() == finished  # the resume changed nothing there
    assert study.trials[1].user_attrs[ATTR_WORKER]["pid"] != study.trials[0].user_attrs[ATTR_WORKER]["pid"]


@pytest.mark.parametrize("how", ["SIGKILL", "SIGTERM"])
def test_a_resume_waits_for_a_job_still_running_and_adopts_it(tmp_path, how):
    """Budget 1, spent by the orphan: the resume runs nothing, waits for the job, adopts it.
    SIGTERM (as SIGINT): the stopped sweep leaves the trial running, since its job goes on."""
    sweep = tmp_path / "sweep"
    command = [*LOCAL, "hydra.sweeper.n_trials=1", "sleep=12",
               "hydra.sweeper.heartbeat_interval=0.5"]  # 12 s: the job outlives a SIGTERM (3 s)
    proc = _start(sweep, *command)
    wait_for(lambda: _status_is(sweep / "0", "running"), 30, "trial 0's job running")
    stopped = time.time()
    if how == "SIGKILL":
        proc.kill()
        proc.wait()
    else:
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=30) == 143
        stderr = (tmp_path / "sweep.err").read_text()
        assert ("aslexp quadratic: interrupted (SIGTERM): trial 0 left running: its job (pid "
                f"{_run(sweep / '0')['process']['pid']} on ") in stderr, stderr[-3000:]
        assert "goes on; the same command resumes the sweep, waits for it and adopts its result" in stderr
    assert _status_is(sweep / "0", "running")
    assert load_study(sweep).trials[0].state == TrialState.RUNNING
    # The job keeps its trial's heartbeat fresh: a sweep on another host could tell it still runs.
    wait_for(lambda: load_study(sweep).trials[0].user_attrs.get(ATTR_HEARTBEAT, 0) > stopped, 10,
             "a heartbeat from the orphaned job")

    resumed = run_sweep(sweep, *command)
    log = resumed.stdout + resumed.stderr
    assert "budget spent (1/1 trials); waiting for trial 0 to adopt its result" in log
    assert "still runs" in log and "trial 0 complete (value" in log
    assert _status_is(sweep / "0", "completed")  # the resume ended after its job, not before
    _assert_one_story(sweep, budget=1, adopted=0)


def test_a_job_that_starts_after_its_trial_was_given_up_does_not_run(tmp_path):
    """A trial finished in the study (here: complete) is never run by a late job: say a Slurm job
    that waited in the queue while its sweep died and a resume ran a replacement."""
    sweep = tmp_path / "sweep"
    run_sweep(sweep, "hydra.sweeper.n_trials=1")
    trial = load_study(sweep).trials[0]
    context = {"storage": str(sweep / "optuna.journal"), "study_name": "quadratic",
               "trial_id": trial._trial_id, "number": 0, "pruner": {}}
    late = tmp_path / "late"
    result = job_process.run([sys.executable, "-m", "aslexp.jobs.quadratic", f"hydra.run.dir={late}"],
                            cwd=tmp_path, capture_output=True, text=True, timeout=60,
                            env={**os.environ, "ASLEXP_TRIAL": json.dumps(context)})
    assert result.returncode == 1
    message = ("TrialGivenUp: trial 0 of study 'quadratic' is already complete in the study: its "
               "sweep gave it up before this job started; the job does not run it")
    assert message in result.stderr
    run = _run(late)
    assert run["status"] == "failed" and run["error"] == message and run["main_metric"] is None
    assert [t.state for t in load_study(sweep).trials] == [TrialState.COMPLETE]


def test_a_job_on_another_host_is_waited_for_by_heartbeat_and_its_run_json_adopted(tmp_path):
    """Recipe A on a real cluster: the sweep (login node) died, its trial's job runs on a compute
    node, where this host can check no process. The trial's heartbeat (the job refreshes it)
    decides while run.json says running; a completed run.json in the shared folder is adopted;
    a run.json started for another trial is not."""
    journal = str(tmp_path / "optuna.journal")
    study = optuna.create_study(storage=open_storage(journal), study_name="quadratic",
                                direction="maximize")
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)
    worker = {**process_identity(), "pid": int(dead.stdout), "start": "0"}  # gone, this host
    node = {"host": "node17", "boot": "b", "pid": 4242, "start": "9"}
    trial = study.ask({"x": optuna.distributions.FloatDistribution(-1, 1)})
    run_dir = tmp_path / "0"
    (run_dir / ".hydra").mkdir(parents=True)
    for key, value in ((ATTR_WORKER, worker), (ATTR_RUN_DIR, str(run_dir)),
                       (ATTR_HEARTBEAT, time.time())):
        study._storage.set_trial_user_attr(trial._trial_id, key, value)
    record = {"status": "running", "process": node, "slurm": {"job_id": "77"}, "main_metric": None}
    (run_dir / "run.json").write_text(json.dumps(record))

    frozen = study.trials[0]
    verdict = judge_running_trial(frozen, grace_period=60, study_name="quadratic")
    assert verdict.action == "wait" and "pid 4242 on node17, Slurm job 77" in verdict.reason
    late = judge_running_trial(frozen, grace_period=60, now=time.time() + 120)
    assert late.action == INTERRUPTED and "gave no heartbeat for" in late.reason

    context = {"storage": journal, "study_name": "quadratic", "trial_id": trial._trial_id + 5,
               "number": 5}
    (run_dir / ".hydra" / "hydra.yaml").write_text(
        "hydra:\n  job:\n    env_set:\n      ASLEXP_TRIAL: '" + json.dumps(context) + "'\n")
    (run_dir / "run.json").write_text(json.dumps(
        {**record, "status": "completed", "main_metric": {"name": "objective", "value": -0.5}}))
    foreign = judge_running_trial(frozen, 60, study_name="quadratic")  # another trial's run:
    assert foreign.action == INTERRUPTED and foreign.run_dir is None  # neither adopted nor marked

    context.update(trial_id=trial._trial_id, number=0)
    (run_dir / ".hydra" / "hydra.yaml").write_text(
        "hydra:\n  job:\n    env_set:\n      ASLEXP_TRIAL: '" + json.dumps(context) + "'\n")
    settled = settle_stale_trials(study, grace_period=60)
    assert settled.adopted == [0] and not settled.waiting
    adopted = study.trials[0]
    assert adopted.state == TrialState.COMPLETE and adopted.value == -0.5
    assert ATTR_STATE not in adopted.user_attrs


def test_ctrl_c_in_a_terminal_reaches_the_job_too_and_both_say_interrupted_at_once(tmp_path):
    """Ctrl-C signals the whole foreground group: the job records itself interrupted, and the
    sweep, which waits a moment for that, records the trial so before it exits (resume re-runs)."""
    sweep = tmp_path / "sweep"
    with open(tmp_path / "sweep.err", "w") as err:
        proc = subprocess.Popen(sweep_command(sweep, *LOCAL, "hydra.sweeper.n_trials=1", "sleep=30"),
                                cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=err,
                                start_new_session=True,
                                preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    wait_for(lambda: _status_is(sweep / "0", "running"), 30, "trial 0's job running")
    os.killpg(proc.pid, signal.SIGINT)
    assert proc.wait(timeout=30) == 130
    assert ("aslexp quadratic: interrupted (Ctrl-C): trial 0 recorded as interrupted; the same "
            "command resumes the sweep and runs it again") in (tmp_path / "sweep.err").read_text()
    trial = load_study(sweep).trials[0]
    assert trial.state == TrialState.FAIL and trial.user_attrs[ATTR_STATE] == INTERRUPTED
    assert _run(sweep / "0")["status"] == "interrupted"


def test_a_job_started_again_in_a_given_up_trial_s_folder_leaves_its_run_json_as_the_study_has_it(tmp_path):
    """A requeued job (Slurm requeues a preempted or timed-out job with the same arguments) starts
    again in its trial's folder after a resume gave that trial up, recorded it interrupted and ran
    its point again: the job refuses, and the folder's run.json stays byte for byte what the study
    says (interrupted), so `runs list` and the study agree."""
    sweep = tmp_path / "sweep"
    proc = subprocess.Popen(sweep_command(sweep, "hydra.sweeper.n_trials=2", "sleep=30"), cwd=tmp_path,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    wait_for(lambda: (sweep / "0" / "run.json").exists(), 60, "the first trial's run.json")
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    run_sweep(sweep, "hydra.sweeper.n_trials=1", "sleep=0", "hydra.sweeper.continue_study=true")
    lost = load_study(sweep).trials[0]
    assert lost.state == TrialState.FAIL and lost.user_attrs[ATTR_STATE] == INTERRUPTED
    record = sweep / "0" / "run.json"
    before = record.read_bytes()
    assert json.loads(before)["status"] == "interrupted"

    context = {"storage": str(sweep / "optuna.journal"), "study_name": "quadratic",
               "trial_id": lost._trial_id, "number": 0, "pruner": {}}
    overrides = [f"{k}={v}" for k, v in lost.params.items()]
    again = job_process.run([sys.executable, "-m", "aslexp.jobs.quadratic", *overrides, "sleep=30",
                             f"hydra.run.dir={sweep / '0'}"], cwd=tmp_path, capture_output=True, text=True,
                            timeout=60, env={**os.environ, "ASLEXP_TRIAL": json.dumps(context)})  # fmt: skip
    assert again.returncode == 1
    assert ("TrialGivenUp: trial 0 of study 'quadratic' is already fail in the study (" in again.stderr
            and "the job does not run it" in again.stderr), again.stderr[-2000:]
    assert record.read_bytes() == before
    listed = json.loads(run_cli("runs", "list", str(sweep), "--format", "json").stdout)
    assert {Path(row["path"]).name: row["status"] for row in listed} == {"0": "interrupted", "1": "completed"}
    status = run_cli("sweep", "status", str(sweep)).stdout
    assert "interrupted 1" in status and "complete 1" in status, status
