"""The Optuna sweeper end to end: real Hydra multiruns of the quadratic job, real Optuna storage."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import uuid
from pathlib import Path

from sweep_helpers import load_study, run_cli, run_sweep, sweep_command, wait_for
from optuna.trial import TrialState

from aslexp.tuning.worker import ATTR_ERROR, ATTR_RERUN_OF, ATTR_STATE, ATTR_WORKER, INTERRUPTED
import job_process


def _completed(study):
    return {t.number: (t.params, t.value) for t in study.trials if t.state == TrialState.COMPLETE}


def test_budget_is_the_study_total_and_a_rerun_resumes(tmp_path: Path) -> None:
    sweep = tmp_path / "sweep"
    run_sweep(sweep, "hydra.sweeper.n_trials=3")
    first = _completed(load_study(sweep))
    assert sorted(first) == [0, 1, 2]

    run_sweep(sweep, "hydra.sweeper.n_trials=5")
    study = load_study(sweep)
    assert [t.number for t in study.trials] == [0, 1, 2, 3, 4]  # only the 2 missing ones ran
    after = _completed(study)
    assert {n: after[n] for n in first} == first  # finished trials kept, not repeated
    assert len({json.dumps(p, sort_keys=True) for p, _ in after.values()}) == 5  # no replayed points

    again = run_sweep(sweep, "hydra.sweeper.n_trials=5")  # budget spent: nothing to do
    assert len(load_study(sweep).trials) == 5
    assert "budget spent (5/5 trials)" in again.stderr + again.stdout
    # One run directory per trial, named by trial number, each a completed run.
    for number in range(5):
        info = json.loads((sweep / str(number) / "run.json").read_text())
        assert info["status"] == "completed"
        assert info["main_metric"]["value"] == after[number][1]


def test_a_trial_folder_named_from_the_trials_config_reads_that_trials_values(tmp_path: Path) -> None:
    # A subdir of the number alone is named without composing; one that reads the config is composed per trial.
    sweep = tmp_path / "sweep"
    run_sweep(sweep, "hydra.sweeper.n_trials=3", "hydra.sweep.subdir=${hydra.job.num}_x${x}")
    for trial in load_study(sweep).trials:
        folder = sweep / f"{trial.number}_x{trial.params['x']}"
        assert json.loads((folder / "run.json").read_text())["status"] == "completed", sorted(os.listdir(sweep))


def test_failed_and_nan_trials_tell_one_story_in_study_run_folder_and_status(tmp_path: Path) -> None:
    """A raising trial and a NaN trial: FAIL in the study with the real error, "failed" with the
    same error in their run.json, and the same text in `sweep status`; the sweep goes on."""
    sweep = tmp_path / "sweep"
    run_sweep(sweep, "hydra/sweeper/sampler=random", "hydra.sweeper.n_trials=6",
              "hydra.sweeper.sampler.seed=0", "fail_if='x > 0.4'", "nan_if='x < -0.4'")
    trials = load_study(sweep).trials
    assert len(trials) == 6
    status = run_cli("sweep", "status", str(sweep), cwd=tmp_path).stdout
    for t in trials:
        x = t.params["x"]
        run = json.loads((sweep / str(t.number) / "run.json").read_text())
        if x > 0.4:
            assert t.state == TrialState.FAIL
            assert t.user_attrs[ATTR_ERROR].startswith("RuntimeError: quadratic: fail_if 'x > 0.4' holds")
        elif x < -0.4:
            assert t.state == TrialState.FAIL
            assert t.user_attrs[ATTR_ERROR] == "the objective is nan, not a finite number"
        else:
            assert t.state == TrialState.COMPLETE and math.isfinite(t.value)
            assert run["status"] == "completed" and run["main_metric"]["value"] == t.value
            continue
        assert run["status"] == "failed" and run["error"] == t.user_attrs[ATTR_ERROR]
        assert f"trial {t.number}: {t.user_attrs[ATTR_ERROR]}" in status
    states = {("raise" if t.params["x"] > 0.4 else "nan" if t.params["x"] < -0.4 else "ok")
              for t in trials}
    assert states == {"raise", "nan", "ok"}, "seed 0 gives all three kinds of trial"
    raised = next(t for t in trials if t.params["x"] > 0.4)
    assert "Traceback" in json.loads((sweep / str(raised.number) / "run.json").read_text())["traceback"]


def test_median_pruner_stops_hopeless_trials(tmp_path: Path) -> None:
    sweep = tmp_path / "sweep"
    run_sweep(sweep, "hydra/sweeper/sampler=random", "hydra.sweeper.n_trials=10",
              "hydra.sweeper.pruner.n_startup_trials=3", overlay="quadratic_pruning")
    trials = load_study(sweep).trials
    pruned = [t for t in trials if t.state == TrialState.PRUNED]
    complete = [t for t in trials if t.state == TrialState.COMPLETE]
    assert pruned and complete
    for t in complete:
        assert sorted(t.intermediate_values) == [0, 1, 2, 3, 4]
    for t in pruned:
        assert max(t.intermediate_values) < 4  # stopped before the last step
        run = json.loads((sweep / str(t.number) / "run.json").read_text())
        assert run["status"] == "pruned"


def test_pruner_none_lets_every_trial_finish(tmp_path: Path) -> None:
    sweep = tmp_path / "sweep"
    run_sweep(sweep, "hydra/sweeper/sampler=random", "hydra.sweeper.n_trials=6",
              "hydra/sweeper/pruner=none", overlay="quadratic_pruning")
    trials = load_study(sweep).trials
    assert [t.state for t in trials] == [TrialState.COMPLETE] * 6


def test_hyperband_pruner_from_config(tmp_path: Path) -> None:
    sweep = tmp_path / "sweep"
    run_sweep(sweep, "hydra/sweeper/sampler=random", "hydra.sweeper.n_trials=10",
              "hydra/sweeper/pruner=hyperband", "hydra.sweeper.pruner.max_resource=5",
              overlay="quadratic_pruning")
    study = load_study(sweep)
    states = [t.state for t in study.trials]
    assert len(states) == 10 and TrialState.PRUNED in states
    assert json.loads((sweep / "sweep.json").read_text())["pruner"]["name"] == "hyperband"



def _count(sweep: Path, state: TrialState) -> int:
    if not (sweep / "optuna.journal").exists() or not (sweep / "sweep.json").exists():
        return 0
    return sum(1 for t in load_study(sweep).trials if t.state == state)


def test_sigkill_mid_sweep_then_resume_loses_no_finished_trial(tmp_path: Path) -> None:
    sweep = tmp_path / "sweep"
    proc = subprocess.Popen(sweep_command(sweep, "hydra.sweeper.n_trials=6", "sleep=0.6"),
                            cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    def two_finished_one_drawn() -> bool:
        # the running trial with both x and y drawn: a kill between the two draws leaves no whole
        # point to run again (the resume then draws afresh), a race this test is not about
        if _count(sweep, TrialState.COMPLETE) < 2:
            return False
        running = [t for t in load_study(sweep).trials if t.state == TrialState.RUNNING]
        return len(running) == 1 and set(running[0].params) == {"x", "y"}

    try:
        wait_for(two_finished_one_drawn, 60, "2 finished trials and a running one with its point drawn")
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    before = _completed(load_study(sweep))
    killed = [t.number for t in load_study(sweep).trials if t.state == TrialState.RUNNING]
    assert len(killed) == 1

    run_sweep(sweep, "hydra.sweeper.n_trials=6", "sleep=0.6")  # the same command
    study = load_study(sweep)
    after = _completed(study)
    assert {n: after[n] for n in before} == before  # every finished trial survived
    assert len(after) == 6  # interrupted trials do not count: the budget is met with completes
    lost = study.trials[killed[0]]
    assert lost.state == TrialState.FAIL and lost.user_attrs[ATTR_STATE] == INTERRUPTED
    assert "died while running this trial" in lost.user_attrs[ATTR_ERROR]
    rerun = study.trials[killed[0] + 1]  # the resume's first trial runs the lost point again
    assert rerun.params == lost.params and rerun.user_attrs[ATTR_RERUN_OF] == lost.number


def test_sigint_marks_the_running_trial_interrupted_and_resume_completes(tmp_path: Path) -> None:
    sweep = tmp_path / "sweep"
    # A budget the sweep cannot finish before the signal, however slowly this machine polls: with
    # 4 trials a late poll could see the last trial running and signal a process that had exited.
    # SIG_DFL in the child: a shell's background job (`cmd &`, as CI runners may start the suite)
    # ignores SIGINT, the ignore is inherited, and Python then installs no KeyboardInterrupt.
    proc = subprocess.Popen(sweep_command(sweep, "hydra.sweeper.n_trials=30", "sleep=0.8"),
                            cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True, start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    def job_running() -> bool:
        running = [t for t in load_study(sweep).trials if t.state == TrialState.RUNNING] \
            if _count(sweep, TrialState.COMPLETE) >= 1 else []
        run_file = sweep / str(running[0].number) / "run.json" if running else None
        return bool(run_file and run_file.exists()
                    and json.loads(run_file.read_text())["status"] == "running")

    wait_for(job_running, 60, "a finished trial and a running job")
    os.killpg(proc.pid, signal.SIGINT)
    _, stderr = proc.communicate(timeout=30)
    assert proc.returncode != 0, stderr[-3000:]
    assert "recorded as interrupted; the same command resumes the sweep and runs it again" in stderr
    study = load_study(sweep)
    interrupted = [t for t in study.trials if t.user_attrs.get(ATTR_STATE) == INTERRUPTED]
    assert len(interrupted) == 1 and interrupted[0].state == TrialState.FAIL
    assert not [t for t in study.trials if t.state == TrialState.RUNNING]
    run = json.loads((sweep / str(interrupted[0].number) / "run.json").read_text())
    assert run["status"] == "interrupted"

    completed = _count(sweep, TrialState.COMPLETE)
    # The same command with a budget that ends sooner (interrupted trials do not count).
    run_sweep(sweep, f"hydra.sweeper.n_trials={completed + 2}", "sleep=0.8")
    assert _count(sweep, TrialState.COMPLETE) == completed + 2
    # It runs the interrupted point again, as the Ctrl-C line said.
    rerun = [t for t in load_study(sweep).trials if t.user_attrs.get(ATTR_RERUN_OF) is not None]
    assert len(rerun) == 1 and rerun[0].user_attrs[ATTR_RERUN_OF] == interrupted[0].number
    assert rerun[0].params == interrupted[0].params and rerun[0].state == TrialState.COMPLETE


def _assert_each_trial_ran_once(sweep: Path, study, n_trials: int) -> set[int]:
    trials = study.trials
    assert len(trials) == n_trials
    assert sorted(t.number for t in trials) == list(range(n_trials))
    assert all(t.state == TrialState.COMPLETE for t in trials)
    for t in trials:
        log = (sweep / str(t.number) / "quadratic.log").read_text()
        assert log.count("objective(") == 1, f"trial {t.number} ran {log.count('objective(')} times"
    return {t.user_attrs[ATTR_WORKER]["pid"] for t in trials}


def test_two_workers_started_by_hand_share_one_journal(tmp_path: Path) -> None:
    sweep = tmp_path / "sweep"
    sweep.mkdir()
    # Trials long enough (1 s) that a worker still starting up on a loaded 2-core machine gets some.
    procs = [subprocess.Popen(sweep_command(sweep, "hydra.sweeper.n_trials=8", "sleep=1.0"),
                              cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                              text=True) for _ in range(2)]
    for proc in procs:
        _, err = proc.communicate(timeout=120)
        assert proc.returncode == 0, err
    pids = _assert_each_trial_ran_once(sweep, load_study(sweep), 8)
    assert pids == {p.pid for p in procs}  # both workers ran trials


def test_n_workers_spawns_asynchronous_workers(tmp_path: Path) -> None:
    sweep = tmp_path / "sweep"
    run_sweep(sweep, "hydra.sweeper.n_trials=6", "hydra.sweeper.n_workers=2", "sleep=1.0")
    pids = _assert_each_trial_ran_once(sweep, load_study(sweep), 6)
    assert len(pids) == 2


def test_two_workers_share_one_postgresql_study(tmp_path: Path, pg_url: str) -> None:
    sweep = tmp_path / "sweep"
    name = f"test_{uuid.uuid4().hex[:10]}"
    overrides = [f"hydra.sweeper.storage='{pg_url}'", f"hydra.sweeper.study_name={name}",
                 "hydra.sweeper.n_trials=6", "hydra.sweeper.n_workers=2", "sleep=1.0"]
    run_sweep(sweep, *overrides)
    study = load_study(sweep, storage=pg_url, name=name)
    assert len(_assert_each_trial_ran_once(sweep, study, 6)) == 2
    info = json.loads((sweep / "sweep.json").read_text())
    assert ":aslexp@" not in info["storage"] and "aslexp@127.0.0.1" in info["storage"]  # no password
    run_sweep(sweep, *overrides[:2], "sleep=1.0", "hydra.sweeper.n_trials=7")  # resume: the same sweep, a larger budget
    assert len(load_study(sweep, storage=pg_url, name=name).trials) == 7


def test_postgresql_needs_an_explicit_study_name(tmp_path: Path, pg_url: str) -> None:
    result = run_sweep(tmp_path / "sweep", f"hydra.sweeper.storage='{pg_url}'", check=False)
    assert result.returncode != 0
    assert "hydra.sweeper.study_name=NAME" in result.stderr


def test_submitit_local_launcher_runs_trials_in_separate_processes(tmp_path: Path) -> None:
    sweep = tmp_path / "sweep"
    run_sweep(sweep, "hydra/launcher=local", "hydra.sweeper.n_trials=2", "steps=3",
              overlay="quadratic_pruning")
    study = load_study(sweep)
    assert [t.state for t in study.trials] == [TrialState.COMPLETE] * 2
    sweeper_pids = {t.user_attrs[ATTR_WORKER]["pid"] for t in study.trials}
    for t in study.trials:
        # The job reported its steps to the study from its own process (loaded from storage).
        assert sorted(t.intermediate_values) == [0, 1, 2]
        run = json.loads((sweep / str(t.number) / "run.json").read_text())
        assert run["status"] == "completed" and run["main_metric"]["value"] == t.value
        assert "submitit" in " ".join(run["argv"])  # ran in a submitit worker process
    assert (sweep / ".submitit").is_dir() and len(sweeper_pids) == 1


def test_malformed_search_space_fails_before_any_trial(tmp_path: Path) -> None:
    cases = {  # one argv element each, as a shell passes them
        "hydra.sweeper.params.x='interval(1, 0)'": "interval(1.0, 0.0) has low > high",
        "hydra.sweeper.params.x='tag(log, interval(0, 1))'": "log interval needs low > 0",
        "hydra.sweeper.params.x='interval(0,'": "cannot parse",
        "hydra.sweeper.params.x='choice()'": "empty choice is not legal",
        "+hydra.sweeper.params.xx='interval(0, 1)'": "does not fit the job's config",
        "hydra/sweeper/pruner=medain": "Could not find 'hydra/sweeper/pruner/medain'",
        "hydra.sweeper.direction=up": "maximize or minimize",
        "hydra.sweeper.params.x=interval(0, 1)": "Sweeping over Hydra's configuration is not supported",
    }
    for index, (override, message) in enumerate(cases.items()):
        sweep = tmp_path / f"sweep{index}"
        result = job_process.run([*sweep_command(sweep), override], cwd=tmp_path,
                                capture_output=True, text=True, timeout=60)
        assert result.returncode != 0, override
        assert message in result.stderr, f"{override}: {result.stderr}"
        trial_dirs = [p for p in sweep.glob("*") if p.is_dir()] if sweep.exists() else []
        assert not trial_dirs, f"{override}: a trial started"


def test_direction_mismatch_with_the_job_stops_the_sweep(tmp_path: Path) -> None:
    sweep = tmp_path / "sweep"
    result = run_sweep(sweep, "hydra.sweeper.direction=minimize", "hydra.sweeper.n_trials=4",
                       check=False)
    assert result.returncode != 0
    assert "set hydra.sweeper.direction=maximize" in result.stderr
    assert len(load_study(sweep).trials) == 1


def test_best_trial_command_reproduces_its_metric(tmp_path: Path) -> None:
    sweep = tmp_path / "sweep"
    run_sweep(sweep, "hydra.sweeper.n_trials=4", "noise=0.05")  # seeded noise: still deterministic
    out = job_process.run([sys.executable, "-m", "aslexp.runs.cli", "sweep", "best", str(sweep),
                          "--json"], capture_output=True, text=True, check=True, cwd=tmp_path)
    best = json.loads(out.stdout)
    assert best["command"].startswith("aslexp quadratic ")
    assert best["python_command"].startswith("python -m aslexp.jobs.quadratic ")
    rerun_dir = tmp_path / "rerun"
    job_process.run([sys.executable, "-m", "aslexp.jobs.quadratic", *best["overrides"],
                    f"hydra.run.dir={rerun_dir}"], check=True, cwd=tmp_path, capture_output=True)
    rerun = json.loads((rerun_dir / "run.json").read_text())
    assert rerun["main_metric"]["value"] == best["value"]  # exactly the same number


def test_a_sweep_that_completes_its_budget_exits_0_although_a_worker_was_killed(tmp_path: Path) -> None:
    """Worker 1 is killed (SIGKILL) in its trial; worker 0 finds the trial lost, runs
    its point again and completes the budget: the sweep did its work, exit 0 with a warning."""
    sweep = tmp_path / "sweep"
    proc = subprocess.Popen(sweep_command(sweep, "hydra.sweeper.n_trials=3",
                                          "hydra.sweeper.n_workers=2", "sleep=1.5"),
                            cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)

    def worker_1_s_trial():
        if not (sweep / "optuna.journal").exists() or not (sweep / "sweep.json").exists():
            return None
        return next((t for t in load_study(sweep).trials if t.state == TrialState.RUNNING
                     and t.user_attrs[ATTR_WORKER]["pid"] != proc.pid
                     and (sweep / str(t.number) / "run.json").exists()), None)

    try:
        wait_for(lambda: worker_1_s_trial() is not None, 60, "worker 1 running a trial")
        victim = worker_1_s_trial()
        os.kill(victim.user_attrs[ATTR_WORKER]["pid"], signal.SIGKILL)
        out, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err[-3000:]
    assert "ended abnormally; the study's budget of 3 trials is complete all the same" in out + err
    trials = load_study(sweep).trials
    lost = trials[victim.number]
    assert lost.state == TrialState.FAIL and lost.user_attrs[ATTR_STATE] == INTERRUPTED
    rerun = [t for t in trials if t.user_attrs.get(ATTR_RERUN_OF) == lost.number]
    assert len(rerun) == 1 and rerun[0].params == lost.params
    assert [t.state for t in trials if t is not lost] == [TrialState.COMPLETE] * 3
