"""One sweep worker: ask -> run -> tell, until the study's trial budget is spent.

Any number of workers (processes on one machine, or jobs on many) run this loop against one
study. Guarantees, for journal-file, SQLite and PostgreSQL storages:

* **Budget.** ``n_trials`` is the study's total budget, not a per-process count. Every trial
  counts except those *interrupted* (their worker died or was stopped). "Count, then ask" runs
  under :func:`aslexp.tuning.storage.budget_lock`, so all workers together never start more than
  ``n_trials`` counted trials, and a resumed sweep runs exactly the missing ones.
* **No trial twice.** Each trial is created by ``study.ask()`` in the storage (atomic in the
  journal file and in the database) and run by the worker that created it only.
* **Dead workers.** A RUNNING trial whose worker is gone is marked FAIL with
  ``aslexp_state = "interrupted"`` before anyone counts: at once when the worker ran on this host
  and its process no longer exists (a zombie counts as gone), otherwise when its heartbeat is
  older than ``grace_period``. Interrupted trials do not count, so the sweep runs a replacement.
* **One story.** The trial's run folder is known before its job starts; whenever the study
  records a trial as interrupted, a run.json still saying "running" says so too.
* **Signals.** Ctrl-C or SIGTERM records the running trial as interrupted; further signals
  during that bookkeeping are held off, so it is never cut in half.
"""

from __future__ import annotations

import logging
import math
import threading
import time
import traceback
from collections import Counter
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from datetime import datetime, timezone
from typing import Any

import optuna
from optuna.distributions import BaseDistribution
from optuna.trial import FrozenTrial, Trial, TrialState

from aslexp.runs.process import process_identity, process_is_gone, sigterm_raises, signals_held
from aslexp.runs.record import mark_interrupted
from aslexp.tuning.storage import budget_lock

log = logging.getLogger(__name__)

ATTR_STATE = "aslexp_state"          # "interrupted" for trials lost to a dead or stopped worker
ATTR_ERROR = "aslexp_error"          # why a trial failed (exception text, NaN, ...)
ATTR_WORKER = "aslexp_worker"        # {"host", "boot", "pid", "start"} of the worker running it
ATTR_HEARTBEAT = "aslexp_heartbeat"  # unix time of the worker's last sign of life
ATTR_OVERRIDES = "aslexp_overrides"  # the trial's Hydra task overrides, as passed to the job
ATTR_RUN_DIR = "aslexp_run_dir"      # the trial's run directory
INTERRUPTED = "interrupted"

_ERROR_CHARS = 4000


class DirectionMismatchError(RuntimeError):
    """The job says its main metric goes the other way than the study optimises."""


@dataclass
class Outcome:
    """What became of one trial's job."""

    state: str                    # "complete" | "pruned" | "failed" | "interrupted"
    value: float | None = None
    error: str | None = None
    run_dir: str | None = None
    goal: str | None = None       # the job's own main-metric goal, if it recorded one
    metric: str | None = None


@dataclass
class WorkerSummary:
    trials: list[int] = field(default_factory=list)
    states: Counter = field(default_factory=Counter)
    stale_failed: list[int] = field(default_factory=list)


# --------------------------------------------------------------------------- worker identity

worker_identity = process_identity  # {"host", "boot", "pid", "start"} of this process
worker_is_dead = process_is_gone    # True only for a process of this machine that is gone


# --------------------------------------------------------------------------- trial bookkeeping


def is_interrupted(trial: FrozenTrial) -> bool:
    return trial.state == TrialState.FAIL and trial.user_attrs.get(ATTR_STATE) == INTERRUPTED


def counts_toward_budget(trial: FrozenTrial) -> bool:
    return not is_interrupted(trial)


def budget_used(trials: Iterable[FrozenTrial]) -> int:
    return sum(1 for t in trials if counts_toward_budget(t))


def state_counts(trials: Iterable[FrozenTrial]) -> Counter:
    """Trials by state, with interrupted failures counted apart from the trials' own failures."""
    counts: Counter = Counter()
    for t in trials:
        counts[INTERRUPTED if is_interrupted(t) else t.state.name.lower()] += 1
    return counts


def _mark_failed(study: optuna.Study, trial_id: int, error: str, interrupted: bool) -> bool:
    """FAIL a trial with its reason; False when someone else finished it first."""
    storage = study._storage
    try:
        if interrupted:
            storage.set_trial_user_attr(trial_id, ATTR_STATE, INTERRUPTED)
        storage.set_trial_user_attr(trial_id, ATTR_ERROR, error[:_ERROR_CHARS])
        return storage.set_trial_state_values(trial_id, TrialState.FAIL)
    except (RuntimeError, ValueError):  # UpdateFinishedTrialError and friends
        return False


def fail_stale_trials(study: optuna.Study, grace_period: float, now: float | None = None,
                      trials: Iterable[FrozenTrial] | None = None) -> list[int]:
    """Mark trials of dead workers FAIL (interrupted); returns their numbers.

    ``trials``: the study's trials if the caller has just read them (saves a storage read).
    """
    now = time.time() if now is None else now
    failed = []
    if trials is None:
        trials = study.get_trials(deepcopy=False, states=(TrialState.RUNNING,))
    for t in trials:
        if t.state != TrialState.RUNNING:
            continue
        identity = t.user_attrs.get(ATTR_WORKER)
        if not identity:
            continue  # not started by an aslexp worker: not ours to judge
        beat = t.user_attrs.get(ATTR_HEARTBEAT)
        if beat is None and t.datetime_start is not None:
            beat = t.datetime_start.timestamp()
        if worker_is_dead(identity):
            reason = (f"worker pid {identity.get('pid')} on {identity.get('host')} died while "
                      "running this trial")
        elif beat is not None and now - float(beat) > grace_period:
            reason = (f"no heartbeat from worker pid {identity.get('pid')} on "
                      f"{identity.get('host')} for {now - float(beat):.0f} s "
                      f"(grace period {grace_period:.0f} s)")
        else:
            continue
        if _mark_failed(study, t._trial_id, reason, interrupted=True):
            log.warning("trial %d marked failed (interrupted): %s", t.number, reason)
            _mark_run_interrupted(t.user_attrs.get(ATTR_RUN_DIR), reason)
            failed.append(t.number)
    return failed


def _mark_run_interrupted(run_dir: str | None, reason: str) -> None:
    """The trial's run.json says interrupted too (if it still says running)."""
    if run_dir:
        try:
            mark_interrupted(run_dir, reason)
        except OSError as err:  # an unreachable folder must not stop the sweep
            log.warning("could not mark %s interrupted: %s", run_dir, err)


class Heartbeat:
    """Refreshes a running trial's heartbeat from a background thread."""

    def __init__(self, study: optuna.Study, trial_id: int, interval: float) -> None:
        self._storage = study._storage
        self._trial_id = trial_id
        self._interval = interval
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="aslexp-heartbeat", daemon=True)

    def _run(self) -> None:
        while not self._stop.wait(self._interval):
            try:
                self._storage.set_trial_user_attr(self._trial_id, ATTR_HEARTBEAT, time.time())
            except Exception as err:  # noqa: BLE001 - finished trial, storage hiccup: stop quietly
                log.debug("heartbeat of trial id %d stopped: %s", self._trial_id, err)
                return

    def __enter__(self) -> "Heartbeat":
        if self._interval > 0:
            self._thread.start()
        return self

    def __exit__(self, *exc: Any) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=5)


def record_outcome(study: optuna.Study, trial: Trial, outcome: Outcome) -> str:
    """Tell the study what happened; returns the state actually recorded."""
    trial_id = trial._trial_id
    storage = study._storage
    try:
        if outcome.run_dir:
            storage.set_trial_user_attr(trial_id, ATTR_RUN_DIR, outcome.run_dir)
        if outcome.state == "complete":
            value = outcome.value
            if value is None or not math.isfinite(value):
                outcome.error = f"objective returned {value} (not a finite number)"
                return _fail(study, trial, outcome.error)
            study.tell(trial, values=[value])
            return "complete"
        if outcome.state == "pruned":
            study.tell(trial, state=TrialState.PRUNED)
            return "pruned"
        if outcome.state == INTERRUPTED:
            _mark_failed(study, trial_id, outcome.error or "interrupted", interrupted=True)
            _mark_run_interrupted(outcome.run_dir, outcome.error or "interrupted")
            return INTERRUPTED
        return _fail(study, trial, outcome.error or "failed")
    except (RuntimeError, ValueError) as err:  # finished meanwhile (e.g. failed as stale)
        log.warning("trial %d: could not record %s: %s", trial.number, outcome.state, err)
        return "unrecorded"


def _fail(study: optuna.Study, trial: Trial, error: str) -> str:
    _mark_failed(study, trial._trial_id, error, interrupted=False)
    return "failed"


# --------------------------------------------------------------------------- the loop


@dataclass
class WorkerSettings:
    storage_spec: str
    study_name: str
    n_trials: int
    grace_period: float = 120.0
    heartbeat_interval: float = 30.0
    worker_label: str = "worker 0"


def run_worker(
    study: optuna.Study,
    distributions: Mapping[str, BaseDistribution],
    settings: WorkerSettings,
    launch: Callable[[Trial], Outcome],
    on_asked: Callable[[Trial], None] | None = None,
) -> WorkerSummary:
    """Run trials until the study's budget is spent; ``launch`` runs one trial's job.

    ``on_asked(trial)`` runs under the budget lock right after the trial is created (the
    sweeper records the trial's overrides and run folder there).
    """
    with sigterm_raises():
        return _run_worker(study, distributions, settings, launch, on_asked)


def _run_worker(study: optuna.Study, distributions: Mapping[str, BaseDistribution],
                settings: WorkerSettings, launch: Callable[[Trial], Outcome],
                on_asked: Callable[[Trial], None] | None) -> WorkerSummary:
    summary = WorkerSummary()
    identity = worker_identity()
    trial: Trial | None = None
    try:
        while True:
            trial = None
            with budget_lock(settings.storage_spec, settings.study_name):
                trials = study.get_trials(deepcopy=False)
                stale = fail_stale_trials(study, settings.grace_period, trials=trials)
                summary.stale_failed += stale
                used = budget_used(study.get_trials(deepcopy=False) if stale else trials)
                if used >= settings.n_trials:
                    log.info("%s: budget spent (%d/%d trials); stopping",
                             settings.worker_label, used, settings.n_trials)
                    break
                # No heartbeat yet: until the first one, the trial's start time stands for it.
                trial = ask_claimed(study, distributions, identity)
                if on_asked is not None:
                    on_asked(trial)
            log.info("%s: trial %d (%d/%d) %s", settings.worker_label, trial.number, used + 1,
                     settings.n_trials, trial.params)
            started = time.monotonic()
            try:
                with Heartbeat(study, trial._trial_id, settings.heartbeat_interval):
                    outcome = launch(trial)
            except Exception as err:  # noqa: BLE001 - a launcher error fails this trial only
                log.error("trial %d could not be launched:\n%s", trial.number,
                          "".join(traceback.format_exception(err)))
                text = " ".join(str(err).split())  # one line (cluster errors come in several)
                outcome = Outcome("failed", error=f"launch failed: {type(err).__name__}: {text}")
            recorded = record_outcome(study, trial, outcome)
            summary.trials.append(trial.number)
            summary.states[recorded] += 1
            shown = f"{outcome.value:.6g}" if outcome.value is not None else "-"
            log.info("%s: trial %d %s (value %s, %.1f s)%s", settings.worker_label, trial.number,
                     recorded, shown, time.monotonic() - started,
                     f": {outcome.error}" if recorded == "failed" else "")
            trial = None
            _check_direction(study, outcome)
    except KeyboardInterrupt as err:
        if trial is not None:  # asked but not yet told: give it back for a resume to re-run
            what = "SIGTERM" if "SIGTERM" in str(err) else "Ctrl-C"
            reason = f"interrupted ({what}) in {settings.worker_label}"
            with signals_held():
                record_outcome(study, trial, Outcome(INTERRUPTED, error=reason,
                                                     run_dir=trial_run_dir(study, trial)))
            log.debug("trial %d %s", trial.number, reason)
            err.aslexp_note = (f"trial {trial.number} recorded as interrupted; the same command "  # type: ignore[attr-defined]
                               "resumes the sweep and runs it again")
        raise
    return summary


def ask_claimed(study: optuna.Study, distributions: Mapping[str, BaseDistribution],
                identity: Mapping[str, Any]) -> Trial:
    """``study.ask(distributions)`` with the worker's identity written by the same storage
    operation that creates the trial.

    Asking first and tagging after left a window: a worker killed between the two writes left a
    RUNNING trial with no owner, which no one may judge dead and which counted toward the budget
    for ever (a resumed sweep then stopped one trial short). Journal and RDB storages both create
    a trial from a template in one append or one transaction.
    """
    study._thread_local.cached_all_trials = None  # what Study.ask does: sync once per trial
    trial_id = study._pop_waiting_trial_id()  # an enqueued trial exists already: tag it after
    if trial_id is None:
        template = FrozenTrial(
            number=-1, state=TrialState.RUNNING, value=None, values=None,
            datetime_start=datetime.now(timezone.utc), datetime_complete=None, params={},
            distributions={}, user_attrs={ATTR_WORKER: dict(identity)}, system_attrs={},
            intermediate_values={}, trial_id=-1)
        trial_id = study._storage.create_new_trial(study._study_id, template_trial=template)
    else:
        study._storage.set_trial_user_attr(trial_id, ATTR_WORKER, dict(identity))
    trial = optuna.Trial(study, trial_id)
    for name, distribution in distributions.items():
        trial._suggest(name, distribution)
    return trial


def trial_run_dir(study: optuna.Study, trial: Trial) -> str | None:
    """The run folder recorded for ``trial`` when it was asked for (None if none was)."""
    try:
        return study._storage.get_trial_user_attrs(trial._trial_id).get(ATTR_RUN_DIR)
    except Exception:  # noqa: BLE001 - bookkeeping only
        return None


def _check_direction(study: optuna.Study, outcome: Outcome) -> None:
    if outcome.goal is None:
        return
    goal = str(outcome.goal).lower()
    direction = study.direction.name.lower()
    if goal in ("maximize", "minimize") and goal != direction:
        raise DirectionMismatchError(
            f"the job records its main metric {outcome.metric!r} with goal {goal!r}, but the "
            f"study {study.study_name!r} is set to {direction}: set "
            f"hydra.sweeper.direction={goal} (in the sweep overlay) and start a new sweep"
        )
