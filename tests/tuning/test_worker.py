"""The worker's bookkeeping on a real journal storage: budget, dead workers, heartbeats, reporter."""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
from pathlib import Path

import optuna
import pytest
from optuna.distributions import FloatDistribution
from optuna.trial import TrialState

from aslexp.tuning.algorithms import AlgorithmSpecError, PerTrialSeedSampler, make_pruner, make_sampler
from aslexp.tuning.context import ENV_VAR, NullReporter, TrialContext, trial_reporter
from aslexp.tuning.storage import open_storage, redact
from aslexp.tuning.study import StudyError, create_or_resume_study, resolve_study_name
from aslexp.tuning.worker import (
    ATTR_HEARTBEAT,
    ATTR_RERUN_OF,
    ATTR_STATE,
    ATTR_WORKER,
    INTERRUPTED,
    Outcome,
    WorkerSettings,
    ask_claimed,
    budget_complete,
    budget_used,
    fail_stale_trials,
    interrupted_to_rerun,
    run_worker,
    worker_identity,
)

SPACE = {"x": FloatDistribution(-1, 1)}


@pytest.fixture
def journal(tmp_path: Path) -> str:
    return str(tmp_path / "optuna.journal")


def _study(spec: str) -> optuna.Study:
    return create_or_resume_study(spec, "unit", "maximize", pruner=make_pruner({"name": "none"}))


def test_threads_sharing_a_study_respect_the_budget_exactly(journal: str) -> None:
    """Four workers race for the last trials; the lock keeps the total at n_trials."""
    settings = WorkerSettings(storage_spec=journal, study_name="unit", n_trials=9,
                              heartbeat_interval=0)
    ran: list[int] = []

    def launch(trial):
        ran.append(trial.number)
        time.sleep(0.02)
        return Outcome("complete", value=-trial.params["x"] ** 2)

    def worker() -> None:
        study = optuna.load_study(study_name="unit", storage=open_storage(journal))
        run_worker(study, SPACE, settings, launch)

    _study(journal)
    threads = [threading.Thread(target=worker) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    study = _study(journal)
    assert len(study.trials) == 9 and sorted(ran) == list(range(9))
    assert all(t.state == TrialState.COMPLETE for t in study.trials)


def test_a_dead_local_worker_s_trial_is_failed_as_interrupted_and_not_counted(journal: str) -> None:
    study = _study(journal)
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)
    trial = study.ask(SPACE)
    identity = {**worker_identity(), "pid": int(dead.stdout), "start": "0"}
    study._storage.set_trial_user_attr(trial._trial_id, ATTR_WORKER, identity)
    live = study.ask(SPACE)
    study._storage.set_trial_user_attr(live._trial_id, ATTR_WORKER, worker_identity())
    assert budget_used(study.trials) == 2

    assert fail_stale_trials(study, grace_period=3600) == [trial.number]
    frozen = study.trials[trial.number]
    assert frozen.state == TrialState.FAIL and frozen.user_attrs[ATTR_STATE] == INTERRUPTED
    assert study.trials[live.number].state == TrialState.RUNNING  # our own process is alive
    assert budget_used(study.trials) == 1


_KILLED_AFTER_ASK = """
import os, signal, sys
import optuna
from optuna.distributions import FloatDistribution
from aslexp.tuning.storage import open_storage
from aslexp.tuning.worker import ask_claimed, worker_identity
study = optuna.load_study(study_name="unit", storage=open_storage(sys.argv[1]))
ask_claimed(study, {"x": FloatDistribution(-1, 1)}, worker_identity())
os.kill(os.getpid(), signal.SIGKILL)  # dies before running or telling the trial
"""


def test_a_worker_killed_right_after_asking_leaves_a_trial_a_resume_replaces(journal: str) -> None:
    """The trial is born owned (one journal record), so the dead worker is recognised at once.

    When the owner was written after ``ask``, a kill in between left an ownerless RUNNING trial
    that counted toward the budget for ever: a resumed 6-trial sweep stopped at 5 completes.
    """
    _study(journal)
    killed = subprocess.run([sys.executable, "-c", _KILLED_AFTER_ASK, journal])
    assert killed.returncode == -9
    created = [json.loads(line) for line in Path(journal).read_text().splitlines()
               if '"datetime_start"' in line and '"study_id"' in line]
    assert len(created) == 1 and ATTR_WORKER in created[0]["user_attrs"]  # the same record

    settings = WorkerSettings(storage_spec=journal, study_name="unit", n_trials=2,
                              heartbeat_interval=0)
    study = optuna.load_study(study_name="unit", storage=open_storage(journal))
    summary = run_worker(study, SPACE, settings, lambda t: Outcome("complete", value=0.0))
    assert summary.stale_failed == [0]
    trials = study.trials
    assert trials[0].state == TrialState.FAIL and trials[0].user_attrs[ATTR_STATE] == INTERRUPTED
    assert [t.state for t in trials[1:]] == [TrialState.COMPLETE] * 2  # the budget is met
    assert all(t.user_attrs[ATTR_WORKER] for t in trials)


def test_ask_claimed_takes_an_enqueued_trial_first(journal: str) -> None:
    study = _study(journal)
    study.enqueue_trial({"x": 0.25})
    trial = ask_claimed(study, SPACE, worker_identity())
    assert trial.params == {"x": 0.25}
    assert study.trials[0].user_attrs[ATTR_WORKER] == worker_identity()
    assert ask_claimed(study, SPACE, worker_identity()).number == 1


def test_an_enqueued_trial_counts_once_it_runs_so_a_budget_of_one_runs_it(journal: str) -> None:
    study = _study(journal)
    study.enqueue_trial({"x": 0.25})
    assert budget_used(study.trials) == 0  # waiting: not yet part of the budget
    settings = WorkerSettings(storage_spec=journal, study_name="unit", n_trials=1, heartbeat_interval=0)
    summary = run_worker(study, SPACE, settings, lambda t: Outcome("complete", value=t.params["x"]))
    assert summary.trials == [0] and [(t.state, t.params) for t in study.trials] == [(TrialState.COMPLETE, {"x": 0.25})]


def test_a_remote_worker_is_judged_by_its_heartbeat(journal: str) -> None:
    study = _study(journal)
    trial = study.ask(SPACE)
    remote = {"host": "elsewhere", "boot": "b", "pid": 1, "start": "1"}
    study._storage.set_trial_user_attr(trial._trial_id, ATTR_WORKER, remote)
    study._storage.set_trial_user_attr(trial._trial_id, ATTR_HEARTBEAT, time.time())
    assert fail_stale_trials(study, grace_period=60) == []  # fresh heartbeat: alive
    assert fail_stale_trials(study, grace_period=60, now=time.time() + 120) == [trial.number]
    assert "no heartbeat" in study.trials[0].user_attrs["aslexp_error"]


def test_trial_reporter_loads_the_trial_from_storage_and_prunes(journal: str, monkeypatch) -> None:
    assert isinstance(trial_reporter({}), NullReporter)
    pruner = {"name": "threshold", "lower": 0.0}
    study = create_or_resume_study(journal, "unit", "maximize", pruner=make_pruner(pruner))
    trial = study.ask(SPACE)
    context = TrialContext(storage=journal, study_name="unit", trial_id=trial._trial_id,
                           number=trial.number, pruner=pruner)
    monkeypatch.setenv(ENV_VAR, context.to_json())
    reporter = trial_reporter({})
    reporter.report(0.5, 0)
    with pytest.raises(optuna.TrialPruned):
        reporter.report(-1.0, 1)
    assert study.trials[0].intermediate_values == {0: 0.5, 1: -1.0}


def test_specs_and_names_fail_clearly(journal: str) -> None:
    with pytest.raises(AlgorithmSpecError, match="unknown pruner 'medain'"):
        make_pruner({"name": "medain"})
    with pytest.raises(AlgorithmSpecError, match="hydra.sweeper.sampler"):
        make_sampler({"name": "tpe", "no_such_option": 1})
    assert isinstance(make_sampler({"name": "random", "seed": 1}), PerTrialSeedSampler)
    assert not isinstance(make_sampler({"name": "qmc", "seed": 1}), PerTrialSeedSampler)  # seed = design
    assert not isinstance(make_sampler({"name": "tpe"}), PerTrialSeedSampler)  # OS entropy
    with pytest.raises(StudyError, match="study_name=NAME"):
        resolve_study_name("postgresql://u@127.0.0.1/db", None, "quadratic")
    _study(journal)
    assert resolve_study_name(journal, None, "other") == "unit"  # a journal's only study
    with pytest.raises(StudyError, match="optimises"):
        create_or_resume_study(journal, "unit", "minimize")
    assert redact("postgresql://u:secret@h:5432/db") == "postgresql://u@h:5432/db"
    assert json.loads(TrialContext("s", "n", 1, 2).to_json())["number"] == 2


def test_an_interrupted_trial_s_point_runs_again_and_a_point_gets_three_runs_at_most(journal):
    """The point an interruption stopped is run again (the next trial takes it), not
    replaced by another; one that is interrupted every time is given up after three runs."""
    study = _study(journal)
    settings = WorkerSettings(storage_spec=journal, study_name="unit", n_trials=2,
                              heartbeat_interval=0)
    first: dict = {}

    def launch(trial):  # the first point is interrupted whenever it runs
        first.setdefault("x", trial.params["x"])
        if trial.params["x"] == first["x"]:
            return Outcome(INTERRUPTED, error="interrupted (Ctrl-C) in worker 0")
        return Outcome("complete", value=-trial.params["x"] ** 2)

    run_worker(study, SPACE, settings, launch)
    trials = study.trials
    assert [t.params["x"] == first["x"] for t in trials] == [True, True, True, False, False]
    assert [t.user_attrs.get(ATTR_RERUN_OF) for t in trials] == [None, 0, 1, None, None]
    assert [t.state for t in trials] == [TrialState.FAIL] * 3 + [TrialState.COMPLETE] * 2
    assert budget_complete(study, 2) and not budget_complete(study, 3)

    # A point the search space no longer holds (a study continued with another) is not re-run.
    lost = trials[0]
    assert interrupted_to_rerun([lost], SPACE) is lost
    assert interrupted_to_rerun([lost], {"x": FloatDistribution(2, 3)}) is None
    assert interrupted_to_rerun([lost], {**SPACE, "y": FloatDistribution(0, 1)}) is None
