"""One sweep worker: ask -> run -> tell, until the study's trial budget is spent.

Any number of workers (processes on one machine, or jobs on many) run this loop against one
study. Guarantees, for journal-file, SQLite and PostgreSQL storages:

* **Budget.** ``n_trials`` is the study's total budget, not a per-process count. Every trial
  counts except those *interrupted* (their worker died or was stopped). "Count, then ask" runs
  under :func:`aslexp.tuning.storage.budget_lock`, so all workers together never start more than
  ``n_trials`` counted trials, and a resumed sweep runs exactly the missing ones.
* **No trial twice.** Each trial is created by ``study.ask()`` in the storage (atomic in the
  journal file and in the database) and run by the worker that created it only.
* **Dead workers.** A RUNNING trial whose worker is gone (on this host: its process no longer
  exists, a zombie counts as gone; anywhere: its heartbeat is older than ``grace_period``) is
  settled before anyone counts, from its run folder first (:func:`judge_running_trial`): a job
  that finished without its worker (a separate process: submitit's local executor, Slurm) is
  *adopted*, its run.json's result (completed with a finite main metric, pruned, failed) told
  to the study; a job that still runs is waited for (the trial stays RUNNING and counts; the
  worker that spends the budget waits for it before it stops); otherwise the trial is marked
  FAIL with ``aslexp_state = "interrupted"``. Interrupted trials do not count, so the sweep
  runs a replacement.
* **Re-runs.** That replacement runs the interrupted trial's parameters again (a new trial whose
  ``aslexp_rerun_of`` names it; the oldest first, ``_TRIES`` tries per point at most, and only a
  point that still fits the search space): what a Ctrl-C, a dead worker or a full disk stopped
  is measured after all, not replaced by another point.
* **A full disk.** A trial whose own files (run folder, run.json, metrics, checkpoints) find the
  disk full is no result: it is recorded interrupted (not counted, re-run), and its worker pauses
  until the trial's folder has room again, for ``JOURNAL_FULL_DISK_WAIT`` seconds counted from
  the first such trial in a row; then the sweep stops with one line naming the file
  (:class:`aslexp.tuning.storage.DiskFullError`). Its run.json says interrupted, with why, once
  there is room to say it (by the resume at the latest).
* **One story.** The trial's run folder is known before its job starts; whenever the study
  records a trial as interrupted, a run.json still saying "running" says so too.
* **Signals.** Ctrl-C or SIGTERM records the running trial as interrupted; further signals
  during that bookkeeping are held off, so it is never cut in half. A trial whose job runs in
  another process and goes on after the signal (it did not get it: ``kill -INT`` of the sweep
  alone, a Slurm job) is left RUNNING for the resume to adopt; one that ends within
  ``_SETTLE_AFTER_SIGNAL`` seconds is recorded as it ended.
"""

from __future__ import annotations

import errno
import json
import logging
import math
import os
import re
import socket
import threading
import time
import traceback
from collections import Counter
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import optuna
import yaml
from optuna.distributions import BaseDistribution
from optuna.trial import FrozenTrial, Trial, TrialState

from aslexp.errors import ConfigError
from aslexp.files import read_json
from aslexp.process import (
    boot_id,
    process_identity,
    process_is_gone,
    sigterm_raises,
    signals_held,
)
from aslexp.runfile import RUN_FILE, mark_interrupted
from aslexp.tuning.storage import JOURNAL_FULL_DISK_WAIT, DiskFullError, budget_lock, wait_for_space

log = logging.getLogger(__name__)

ATTR_STATE = "aslexp_state"          # "interrupted" for trials lost to a dead or stopped worker
ATTR_ERROR = "aslexp_error"          # why a trial failed (exception text, NaN, ...)
ATTR_WORKER = "aslexp_worker"        # {"host", "boot", "pid", "start"} of the worker running it
ATTR_HEARTBEAT = "aslexp_heartbeat"  # unix time of the last sign of life of the worker or its job
ATTR_OVERRIDES = "aslexp_overrides"  # the trial's Hydra task overrides, as passed to the job
ATTR_RUN_DIR = "aslexp_run_dir"      # the trial's run folder, relative to the sweep folder
ATTR_ADOPTED = "aslexp_adopted"      # why the result came from the run folder, not the worker
ATTR_RERUN_OF = "aslexp_rerun_of"    # the interrupted trial whose parameters this one runs again
INTERRUPTED = "interrupted"
TRIAL_ENV = "ASLEXP_TRIAL"           # = aslexp.tuning.context.ENV_VAR (the job's trial context)

_ERROR_CHARS = 4000
_SETTLE_AFTER_SIGNAL = 3.0  # seconds a stopped worker waits for its job to record how it ended
_ORPHAN_POLL = 1.0          # seconds between looks at orphaned jobs when only they are left
_TRIES = 3                  # runs of one interrupted point at most (one that kills its worker ends)


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
    adopted: list[int] = field(default_factory=list)


# --------------------------------------------------------------------------- worker identity

worker_identity = process_identity  # {"host", "boot", "pid", "start"} of this process
worker_is_dead = process_is_gone    # True only for a process of this machine that is gone


# --------------------------------------------------------------------------- trial bookkeeping


def is_interrupted(trial: FrozenTrial) -> bool:
    return trial.state == TrialState.FAIL and trial.user_attrs.get(ATTR_STATE) == INTERRUPTED


def counts_toward_budget(trial: FrozenTrial) -> bool:
    # An enqueued trial counts once it runs (asking for it takes it), not while it waits.
    return not is_interrupted(trial) and trial.state != TrialState.WAITING


class LaunchRefused(ConfigError):
    """The launcher refused a trial's job for a setting every trial shares (a Slurm memory request
    no node can give): the sweep stops in one line (exit 2) with the trial not counted."""


def budget_used(trials: Iterable[FrozenTrial]) -> int:
    return sum(1 for t in trials if counts_toward_budget(t))


def budget_complete(study: optuna.Study, n_trials: int) -> bool:
    """Whether the study holds ``n_trials`` counted trials and none still runs: the sweep's work
    is done, whatever became of the processes that did it."""
    trials = study.get_trials(deepcopy=False)
    running = any(t.state == TrialState.RUNNING for t in trials)
    return budget_used(trials) >= n_trials and not running


def _fits(params: Mapping[str, Any], distributions: Mapping[str, BaseDistribution]) -> bool:
    """Whether ``params`` is a point of the search space ``distributions`` (all names, in range)."""
    if not params or set(params) != set(distributions):
        return False
    try:
        return all(distributions[name]._contains(distributions[name].to_internal_repr(value))
                   for name, value in params.items())
    except (ValueError, TypeError):  # a choice no longer offered, a value of another type
        return False


def interrupted_to_rerun(trials: Iterable[FrozenTrial],
                         distributions: Mapping[str, BaseDistribution]) -> FrozenTrial | None:
    """The oldest interrupted trial whose parameters no trial runs again yet; None if none.

    A point gets ``_TRIES`` runs at most (one that kills its worker every time ends there), and
    one that no longer fits the search space (a study continued with another) is not re-run.
    """
    trials = sorted(trials, key=lambda t: t.number)
    by_number = {t.number: t for t in trials}
    taken = {t.user_attrs.get(ATTR_RERUN_OF) for t in trials}
    for t in trials:
        if not is_interrupted(t) or t.number in taken or not _fits(t.params, distributions):
            continue
        tries, earlier = 1, t.user_attrs.get(ATTR_RERUN_OF)
        while earlier in by_number and tries < _TRIES:
            tries, earlier = tries + 1, by_number[earlier].user_attrs.get(ATTR_RERUN_OF)
        if tries < _TRIES:
            return t
    return None


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


@dataclass
class Verdict:
    """What to do with a RUNNING trial (see :func:`judge_running_trial`)."""

    action: str                   # "alive" | "wait" | "adopt" | "interrupted"
    reason: str = ""              # why (the worker's fate, and its job's)
    outcome: Outcome | None = None  # "adopt": the job's own result, from its run.json
    run_dir: str | None = None    # the trial's run folder (None: none, or another trial's run)


# The sweep folder of each study this process works on (the sweeper's, or the one a tool
# opened): trial folders are recorded relative to it, so a moved or copied sweep folder finds
# its own trials. Folders recorded as absolute paths (older sweeps) stay as they are.
_SWEEP_DIRS: dict[str, Path] = {}


def register_sweep_dir(study_name: str, sweep_dir: str | os.PathLike) -> None:
    _SWEEP_DIRS[study_name] = Path(sweep_dir)


def run_dir_of(stored: str | None, study_name: str | None) -> str | None:
    """The trial folder a study records (``ATTR_RUN_DIR``) as a path to open here."""
    if not stored:
        return None
    base = _SWEEP_DIRS.get(study_name or "")
    return str(base / stored) if base is not None and not Path(stored).is_absolute() else stored


def stored_run_dir(run_dir: str | None, study_name: str | None) -> str | None:
    """``run_dir`` as the study records it: relative to the sweep folder when inside it."""
    base = _SWEEP_DIRS.get(study_name or "")
    if not run_dir or base is None:
        return run_dir
    path, top = Path(run_dir).resolve(), base.resolve()
    return os.path.relpath(path, top) if path.is_relative_to(top) else run_dir


def read_run_record(run_dir: str | None, trial: FrozenTrial | None = None,
                    study_name: str | None = None) -> dict[str, Any]:
    """The run.json of a trial's run folder, {} when there is none (or it is unreadable).

    With ``trial``: {} as well when the folder's job was started for another trial. The sweeper
    gives every trial a folder of its own (created empty before the job starts, never reused);
    the trial context the sweeper passed to the job (``hydra.job.env_set.ASLEXP_TRIAL``, kept in
    ``.hydra/hydra.yaml``) must also name this trial when it is there.
    """
    if not run_dir or not (Path(run_dir) / RUN_FILE).is_file():
        return {}
    try:
        info = read_json(Path(run_dir) / RUN_FILE)
    except (OSError, ValueError):
        return {}
    if not isinstance(info, dict):
        return {}
    if trial is not None:
        context = _job_trial_context(run_dir)
        if context is not None and (
                context.get("number") != trial.number or context.get("trial_id") != trial._trial_id
                or (study_name is not None and context.get("study_name") != study_name)):
            log.warning("trial %d: %s/%s belongs to trial %s of study %r, not to it: not adopted",
                        trial.number, run_dir, RUN_FILE, context.get("number"),
                        context.get("study_name"))
            return {}
    return info


def _job_trial_context(run_dir: str) -> dict[str, Any] | None:
    """The trial context a job was started with (None when the folder does not say)."""
    path = Path(run_dir) / ".hydra" / "hydra.yaml"
    if not path.is_file():
        return None
    try:
        with open(path, encoding="utf-8") as fh:
            loaded = yaml.safe_load(fh)
        text = (((loaded or {}).get("hydra") or {}).get("job") or {}).get("env_set", {}).get(TRIAL_ENV)
        return json.loads(text) if text else None
    except (OSError, ValueError, AttributeError, yaml.YAMLError):
        return None


def _on_this_host(identity: Mapping[str, Any] | None) -> bool:
    return bool(identity) and identity.get("host") == socket.gethostname() \
        and identity.get("boot") == boot_id()


def _job_where(process: Mapping[str, Any] | None, record: Mapping[str, Any]) -> str:
    where = f"pid {(process or {}).get('pid')} on {(process or {}).get('host')}"
    slurm = record.get("slurm") or {}
    return where + (f", Slurm job {slurm['job_id']}" if slurm.get("job_id") else "")


def _outcome_of_record(record: Mapping[str, Any], run_dir: str) -> Outcome | None:
    """The result a finished run.json records (None while it runs or says nothing)."""
    status = record.get("status")
    main = record.get("main_metric") or {}
    if status == "completed":
        value = main.get("value")
        try:
            value = float(value)
        except (TypeError, ValueError):
            value = None
        if value is None or not math.isfinite(value):
            return Outcome("failed", run_dir=run_dir,
                           error=f"its job completed without its worker, but its {RUN_FILE} "
                                 f"records no finite main metric ({main.get('value')!r})")
        return Outcome("complete", value=value, run_dir=run_dir, goal=main.get("goal"),
                       metric=main.get("name"))
    if status == "pruned":
        return Outcome("pruned", error=record.get("error"), run_dir=run_dir)
    if status == "failed":
        return Outcome("failed", error=record.get("error") or "failed", run_dir=run_dir)
    if status == INTERRUPTED:
        return Outcome(INTERRUPTED, error=record.get("error") or INTERRUPTED, run_dir=run_dir)
    return None


def judge_running_trial(trial: FrozenTrial, grace_period: float, now: float | None = None,
                        study_name: str | None = None) -> Verdict:
    """What a RUNNING trial's state says, its worker's fate and its run folder together.

    * its worker lives (on this host: its process runs; anywhere: a heartbeat within
      ``grace_period``): "alive", not ours to judge (nor a trial no aslexp worker started);
    * the worker is gone, and the trial's run.json records how the job ended: "adopt" that result
      (completed with a finite main metric, pruned, failed; interrupted as interrupted);
    * the worker is gone and the job still runs: on this host its process (run.json's
      ``process``) is alive: "wait"; on another host nothing can be checked there, so the trial's
      heartbeat decides (a job reporting to the study refreshes it too): "wait" within
      ``grace_period``, "interrupted" after;
    * otherwise (no run.json yet, the job's process gone too, or the job ran in the worker's
      own process): "interrupted". A job that starts after that finds its trial finished and
      does not run (:func:`aslexp.tuning.context.trial_reporter`).
    """
    now = time.time() if now is None else now
    identity = trial.user_attrs.get(ATTR_WORKER)
    if trial.state != TrialState.RUNNING or not identity:
        return Verdict("alive")
    beat = trial.user_attrs.get(ATTR_HEARTBEAT)
    if beat is None and trial.datetime_start is not None:
        beat = trial.datetime_start.timestamp()
    silent = beat is not None and now - float(beat) > grace_period
    if worker_is_dead(identity):
        gone = (f"worker pid {identity.get('pid')} on {identity.get('host')} died while running "
                "this trial")
    elif silent:
        gone = (f"no heartbeat from worker pid {identity.get('pid')} on {identity.get('host')} "
                f"for {now - float(beat):.0f} s (grace period {grace_period:.0f} s)")
    else:
        return Verdict("alive")
    run_dir = run_dir_of(trial.user_attrs.get(ATTR_RUN_DIR), study_name)
    record = read_run_record(run_dir, trial, study_name)
    if not record and run_dir and (Path(run_dir) / RUN_FILE).is_file():
        run_dir = None  # another trial's run: never adopted, never marked
    outcome = _outcome_of_record(record, str(run_dir)) if record else None
    if outcome is not None:
        if outcome.state == INTERRUPTED:
            return Verdict(INTERRUPTED, f"{gone}; its job ended interrupted: {outcome.error}",
                           outcome, run_dir)
        return Verdict("adopt", f"{gone}; its job ({_job_where(record.get('process'), record)}) "
                       f"finished {record.get('status')} without it: result adopted from "
                       f"{run_dir}/{RUN_FILE}", outcome, run_dir)
    if record.get("status") == "running":
        process = record.get("process")
        where = _job_where(process, record)
        in_worker = process and all(process.get(k) == identity.get(k)
                                    for k in ("host", "boot", "pid", "start"))
        if in_worker:  # the job ran in the worker's own process: it went with it
            return Verdict(INTERRUPTED, gone, run_dir=run_dir)
        if process and not process_is_gone(process):
            if _on_this_host(process):
                return Verdict("wait", f"{gone}; its job ({where}) still runs", run_dir=run_dir)
            if not silent:
                return Verdict("wait", f"{gone}; its job ({where}) may still run (another host: "
                               f"judged by the trial's heartbeat, grace period {grace_period:.0f} s)",
                               run_dir=run_dir)
            return Verdict(INTERRUPTED, f"{gone}; its job ({where}, another host) gave no "
                           f"heartbeat for {now - float(beat):.0f} s either", run_dir=run_dir)
        return Verdict(INTERRUPTED, f"{gone}; its job ({where}) is gone too", run_dir=run_dir)
    return Verdict(INTERRUPTED, gone, run_dir=run_dir)


@dataclass
class Settled:
    """What :func:`settle_stale_trials` did."""

    interrupted: list[int] = field(default_factory=list)
    adopted: list[int] = field(default_factory=list)
    waiting: dict[int, str] = field(default_factory=dict)  # number -> why

    @property
    def changed(self) -> bool:
        return bool(self.interrupted or self.adopted)


def settle_stale_trials(study: optuna.Study, grace_period: float, now: float | None = None,
                        trials: Iterable[FrozenTrial] | None = None) -> Settled:
    """Settle the RUNNING trials of gone workers (:func:`judge_running_trial`): adopt finished
    jobs' results, mark the lost ones interrupted (run.json included), list the ones to wait for.

    ``trials``: the study's trials if the caller has just read them (saves a storage read).
    """
    settled = Settled()
    if trials is None:
        trials = study.get_trials(deepcopy=False, states=(TrialState.RUNNING,))
    for t in trials:
        if t.state != TrialState.RUNNING:
            continue
        verdict = judge_running_trial(t, grace_period, now, study.study_name)
        if verdict.action == "wait":
            settled.waiting[t.number] = verdict.reason
        elif verdict.action == "adopt":
            recorded = adopt_outcome(study, t, verdict.outcome, verdict.reason)
            if recorded:
                log.warning("trial %d %s (value %s): %s", t.number, recorded,
                            _shown(verdict.outcome.value), verdict.reason)
                settled.adopted.append(t.number)
        elif verdict.action == INTERRUPTED:
            if _mark_failed(study, t._trial_id, verdict.reason, interrupted=True):
                log.warning("trial %d marked failed (interrupted): %s", t.number, verdict.reason)
                _mark_run_interrupted(verdict.run_dir, verdict.reason)
                settled.interrupted.append(t.number)
    return settled


def fail_stale_trials(study: optuna.Study, grace_period: float, now: float | None = None,
                      trials: Iterable[FrozenTrial] | None = None) -> list[int]:
    """:func:`settle_stale_trials`; returns the numbers of the trials marked interrupted."""
    return settle_stale_trials(study, grace_period, now, trials).interrupted


def adopt_outcome(study: optuna.Study, trial: FrozenTrial, outcome: Outcome, reason: str) -> str | None:
    """Tell the study the result a trial's job recorded without its worker; the state recorded,
    None when someone else finished the trial first."""
    storage = study._storage
    try:
        storage.set_trial_user_attr(trial._trial_id, ATTR_ADOPTED, reason[:_ERROR_CHARS])
        if outcome.state == "complete":
            study.tell(trial.number, values=[outcome.value])
            return "complete"
        if outcome.state == "pruned":
            study.tell(trial.number, state=TrialState.PRUNED)
            return "pruned"
    except (RuntimeError, ValueError) as err:  # finished meanwhile
        log.debug("trial %d: not adopted: %s", trial.number, err)
        return None
    interrupted = outcome.state == INTERRUPTED
    if _mark_failed(study, trial._trial_id, outcome.error or outcome.state, interrupted=interrupted):
        return INTERRUPTED if interrupted else "failed"
    return None


def _shown(value: float | None) -> str:
    return f"{value:.6g}" if value is not None else "-"


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
            storage.set_trial_user_attr(trial_id, ATTR_RUN_DIR,
                                        stored_run_dir(outcome.run_dir, study.study_name))
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


# --------------------------------------------------------------------------- a full disk

# A full disk in a trial's error, however it got there: the job's one line ("disk full: cannot
# write FILE ([Errno 28] ...)", aslexp.files.describe_os_error), an OSError's own text (an error
# while recording the error, a launch that failed), or a journal append that gave up.
_FULL_DISK = re.compile(rf"\[Errno ({errno.ENOSPC}|{errno.EDQUOT})\]|: the disk is full;")
_FILE_NAMED = (re.compile(r"cannot write (\S+) \(\["),          # describe_os_error
               re.compile(r"\[Errno \d+\] [^:']*: '([^']+)'"),   # str(OSError) with a file
               re.compile(r"journal file (\S+): the disk is full"))  # JournalWriteError


def disk_full(outcome: Outcome, run_dir: str | None = None) -> str | None:
    """``disk full: cannot write FILE`` when a failed trial failed on a full disk (or quota),
    else None: such a trial is no result, and must not count as one. An error that names no
    file (Hydra writing the trial's .hydra/ says only "No space left on device") names the
    trial's run folder: ``disk full: cannot write in RUN_DIR``."""
    text = outcome.error or ""
    if outcome.state != "failed" or not _FULL_DISK.search(text):
        return None
    kind = "disk quota exceeded" if f"[Errno {errno.EDQUOT}]" in text else "disk full"
    for pattern in _FILE_NAMED:
        found = pattern.search(text)
        if found:
            return f"{kind}: cannot write {found.group(1)}"
    if run_dir:
        return f"{kind}: cannot write in {run_dir}"
    return f"{kind}: {' '.join(text.split())[:300]}"


def _record_disk_full(study: optuna.Study, trial: Trial, run_dir: str | None, reason: str) -> str:
    """The trial in the study: interrupted by the full disk (not counted, re-run). Its run.json
    waits for room (:func:`_mark_run_disk_full`)."""
    try:
        if run_dir:
            study._storage.set_trial_user_attr(trial._trial_id, ATTR_RUN_DIR,
                                               stored_run_dir(run_dir, study.study_name))
    except (RuntimeError, ValueError) as err:  # a journal that cannot be written either
        log.debug("trial %d: run folder not recorded: %s", trial.number, err)
    marked = _mark_failed(study, trial._trial_id, reason, interrupted=True)
    return INTERRUPTED if marked else "unrecorded"


def _mark_run_disk_full(run_dir: str | None, reason: str, quiet: bool = False) -> None:
    """The trial's run.json says it was interrupted, and why: it still says running (its job
    found no room to say more) or failed (with the disk-full error the study does not count)."""
    if not run_dir:
        return
    try:
        mark_interrupted(run_dir, reason, replace=("running", "failed"))
    except OSError as err:
        (log.debug if quiet else log.warning)("could not record %s as interrupted (%s): %s",
                                              Path(run_dir) / RUN_FILE, reason, err)


def _folder_to_probe(reason: str, run_dir: str | None, study_name: str) -> Path:
    """The nearest existing folder of the file the full disk refused (else of the trial's)."""
    named = reason.split("cannot write ", 1)[1].removeprefix("in ") if "cannot write " in reason \
        else None
    for start in (named, run_dir, _SWEEP_DIRS.get(study_name), "."):
        if start:
            folder = Path(start)
            while not folder.is_dir() and folder != folder.parent:
                folder = folder.parent
            if folder.is_dir():
                return folder
    return Path(".")


def _pause_for_space(settings: "WorkerSettings", number: int, run_dir: str | None, reason: str,
                     since: float) -> None:
    """Wait until the trial's folder has room again (the trial runs again after), at most
    ``full_disk_wait`` seconds after ``since``; then stop the sweep in one line."""
    wait = JOURNAL_FULL_DISK_WAIT if settings.full_disk_wait is None else settings.full_disk_wait
    folder = _folder_to_probe(reason, run_dir, settings.study_name)
    log.warning("%s: trial %d stopped on a full disk (%s): it does not count toward the budget and "
                "its parameters run again; waiting up to %.0f s for room in %s",
                settings.worker_label, number, reason, max(0.0, since + wait - time.monotonic()),
                folder)
    if wait_for_space(folder, since + wait):
        log.warning("%s: %s has room again after %.0f s; the sweep goes on", settings.worker_label,
                    folder, time.monotonic() - since)
        _mark_run_disk_full(run_dir, reason)
        return
    _mark_run_disk_full(run_dir, reason, quiet=True)  # most likely no room: the resume does it
    raise DiskFullError(
        f"{reason}: no room came back in {folder} within {wait:.0f} s "
        f"(ASLEXP_JOURNAL_FULL_DISK_WAIT); trial {number} is recorded interrupted and does not "
        "count toward the budget: free space, then run the same command (it runs trial "
        f"{number}'s parameters again)")


def _settle_rerun_run_file(study: optuna.Study, number: int) -> None:
    """The run.json of the interrupted trial now re-run says so too, if a full disk or a dead
    worker left it saying running (a sweep that stopped could not write it)."""
    try:
        earlier = study._storage.get_trial(
            study._storage.get_trial_id_from_study_id_trial_number(study._study_id, number))
    except (KeyError, RuntimeError, ValueError):
        return
    run_dir = run_dir_of(earlier.user_attrs.get(ATTR_RUN_DIR), study.study_name)
    if not run_dir or not read_run_record(run_dir, earlier, study.study_name):
        return  # no run.json, or another trial's
    reason = earlier.user_attrs.get(ATTR_ERROR) or INTERRUPTED
    if reason.startswith(("disk full: ", "disk quota exceeded: ")):
        _mark_run_disk_full(run_dir, reason)
    else:
        _mark_run_interrupted(run_dir, reason)


# --------------------------------------------------------------------------- the loop


@dataclass
class WorkerSettings:
    storage_spec: str
    study_name: str
    n_trials: int
    grace_period: float = 120.0
    heartbeat_interval: float = 30.0
    worker_label: str = "worker 0"
    # Seconds a full disk may refuse trials' files before the sweep stops (None: the journal's
    # JOURNAL_FULL_DISK_WAIT, ASLEXP_JOURNAL_FULL_DISK_WAIT).
    full_disk_wait: float | None = None


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


def _launched(study: optuna.Study, trial: Trial, settings: WorkerSettings,
              launch: Callable[[Trial], Outcome]) -> Outcome:
    """The trial's job run under its heartbeat: its outcome, or a failed one when the launcher
    raised. A launch every trial would meet alike (:class:`LaunchRefused`) records the trial as
    interrupted (not counted) and is raised: the sweep stops."""
    try:
        with Heartbeat(study, trial._trial_id, settings.heartbeat_interval):
            return launch(trial)
    except LaunchRefused as err:  # e.g. a Slurm node too small: the same command, corrected, resumes
        record_outcome(study, trial, Outcome(INTERRUPTED, error=f"not launched: {err}"))
        raise
    except Exception as err:  # noqa: BLE001 - a launcher error fails this trial only
        log.error("trial %d could not be launched:\n%s", trial.number, "".join(traceback.format_exception(err)))
        text = " ".join(str(err).split())  # one line (cluster errors come in several)
        return Outcome("failed", error=f"launch failed: {type(err).__name__}: {text}")


def _run_worker(study: optuna.Study, distributions: Mapping[str, BaseDistribution],
                settings: WorkerSettings, launch: Callable[[Trial], Outcome],
                on_asked: Callable[[Trial], None] | None) -> WorkerSummary:
    summary = WorkerSummary()
    identity = worker_identity()
    trial: Trial | None = None
    waited_for: set[int] = set()
    full_since: float | None = None  # when trials began to find the disk full (None: they do not)
    try:
        while True:
            trial = None
            with budget_lock(settings.storage_spec, settings.study_name):
                trials = study.get_trials(deepcopy=False)
                settled = settle_stale_trials(study, settings.grace_period, trials=trials)
                summary.stale_failed += settled.interrupted
                summary.adopted += settled.adopted
                used = budget_used(study.get_trials(deepcopy=False) if settled.changed else trials)
                if used < settings.n_trials:
                    # No heartbeat yet: until the first one, the trial's start time stands for it.
                    trial = ask_claimed(study, distributions, identity)
                    if on_asked is not None:
                        on_asked(trial)
            if trial is None:
                if not settled.waiting:
                    log.info("%s: budget spent (%d/%d trials); stopping",
                             settings.worker_label, used, settings.n_trials)
                    break
                # Only jobs whose worker is gone are left: wait for them, adopt their results.
                for number in sorted(set(settled.waiting) - waited_for):
                    log.info("%s: budget spent (%d/%d trials); waiting for trial %d to adopt its "
                             "result: %s", settings.worker_label, used, settings.n_trials, number,
                             settled.waiting[number])
                waited_for |= set(settled.waiting)
                time.sleep(_ORPHAN_POLL)
                continue
            rerun_of = trial.user_attrs.get(ATTR_RERUN_OF)
            again = "" if rerun_of is None else f" (trial {rerun_of}'s point again: it was interrupted)"
            log.info("%s: trial %d (%d/%d) %s%s", settings.worker_label, trial.number, used + 1,
                     settings.n_trials, trial.params, again)
            if rerun_of is not None:
                _settle_rerun_run_file(study, rerun_of)
            started = time.monotonic()
            outcome = _launched(study, trial, settings, launch)
            run_dir = outcome.run_dir or trial_run_dir(study, trial)
            full = disk_full(outcome, run_dir)
            if full:  # no result: not counted, re-run, and no trial starts until there is room
                recorded = _record_disk_full(study, trial, run_dir, full)
                full_since = full_since or time.monotonic()
            else:
                recorded = record_outcome(study, trial, outcome)
                full_since = None
            summary.trials.append(trial.number)
            summary.states[recorded] += 1
            log.info("%s: trial %d %s (value %s, %.1f s)%s", settings.worker_label, trial.number,
                     recorded, _shown(outcome.value), time.monotonic() - started,
                     f": {full or outcome.error}" if recorded in ("failed", INTERRUPTED) else "")
            number, trial = trial.number, None
            if full:
                _pause_for_space(settings, number, run_dir, full, full_since)
            _check_direction(study, outcome)
    except KeyboardInterrupt as err:
        if trial is not None:  # asked but not yet told
            what = "SIGTERM" if "SIGTERM" in str(err) else "Ctrl-C"
            reason = f"interrupted ({what}) in {settings.worker_label}"
            with signals_held():
                note = _settle_after_signal(study, trial, reason, settings.worker_label)
            err.aslexp_note = note  # type: ignore[attr-defined]
        raise
    return summary


def _settle_after_signal(study: optuna.Study, trial: Trial, reason: str, label: str) -> str:
    """Record the trial a signal stopped its worker in; the note for the one-line report.

    A job in the worker's own process stopped with it: the trial is interrupted (a resume runs
    it again). A job in another process (submitit's local executor, a Slurm job) may have got
    the signal too (Ctrl-C in a terminal): it gets ``_SETTLE_AFTER_SIGNAL`` seconds to record how
    it ended, which the study then records as well. One that goes on is left RUNNING: the next
    worker waits for it and adopts its result (nothing computed is lost).
    """
    run_dir = trial_run_dir(study, trial)
    frozen = study._storage.get_trial(trial._trial_id)
    deadline = time.monotonic() + _SETTLE_AFTER_SIGNAL
    while True:
        record = read_run_record(run_dir, frozen, study.study_name)
        process = record.get("process")
        elsewhere = (record.get("status") == "running" and process
                     and not (_on_this_host(process) and process.get("pid") == os.getpid())
                     and not process_is_gone(process))
        if not elsewhere or time.monotonic() >= deadline:
            break
        time.sleep(0.1)
    outcome = _outcome_of_record(record, str(run_dir)) if record else None
    if outcome is not None and outcome.state != INTERRUPTED:
        recorded = adopt_outcome(study, frozen, outcome,
                                 f"{reason}; its job ({_job_where(process, record)}) finished "
                                 f"{record.get('status')}: result taken from {run_dir}/{RUN_FILE}")
        log.info("%s: trial %d %s (value %s) as its job ended", label, trial.number, recorded,
                 _shown(outcome.value))
        return f"trial {trial.number} recorded as {recorded}, as its job ended"
    if elsewhere:
        log.info("%s: trial %d left running: its job (%s) goes on", label, trial.number,
                 _job_where(process, record))
        return (f"trial {trial.number} left running: its job ({_job_where(process, record)}) goes "
                "on; the same command resumes the sweep, waits for it and adopts its result")
    record_outcome(study, trial, Outcome(INTERRUPTED, error=reason, run_dir=run_dir))
    log.debug("trial %d %s", trial.number, reason)
    return (f"trial {trial.number} recorded as interrupted; the same command resumes the sweep "
            "and runs it again")


def ask_claimed(study: optuna.Study, distributions: Mapping[str, BaseDistribution],
                identity: Mapping[str, Any]) -> Trial:
    """``study.ask(distributions)`` with the worker's identity written by the same storage
    operation that creates the trial.

    Asking first and tagging after left a window: a worker killed between the two writes left a
    RUNNING trial with no owner, which no one may judge dead and which counted toward the budget
    for ever (a resumed sweep then stopped one trial short). Journal and RDB storages both create
    a trial from a template in one append or one transaction.

    The trial is, in this order: one enqueued by hand (``Study.enqueue_trial``); the point of an
    interrupted trial not yet run again (:func:`interrupted_to_rerun`), ``aslexp_rerun_of``
    naming it; a new point from the sampler. Call it under :func:`budget_lock`, so that two
    workers never take the same interrupted point.
    """
    study._thread_local.cached_all_trials = None  # what Study.ask does: sync once per trial
    trial_id = study._pop_waiting_trial_id()  # an enqueued trial exists already: tag it after
    if trial_id is None:
        # An interrupted trial's point comes before a new one (its parameters in the same record:
        # fixed, as Study.enqueue_trial fixes them).
        rerun = interrupted_to_rerun(study.get_trials(deepcopy=False), distributions)
        params = dict(rerun.params) if rerun is not None else {}
        user_attrs: dict[str, Any] = {ATTR_WORKER: dict(identity)}
        if rerun is not None:
            user_attrs[ATTR_RERUN_OF] = rerun.number
        template = FrozenTrial(
            number=-1, state=TrialState.RUNNING, value=None, values=None,
            datetime_start=datetime.now(timezone.utc), datetime_complete=None, params=params,
            distributions={name: distributions[name] for name in params}, user_attrs=user_attrs,
            system_attrs={"fixed_params": params} if params else {},
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
        return run_dir_of(study._storage.get_trial_user_attrs(trial._trial_id).get(ATTR_RUN_DIR),
                          study.study_name)
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
