"""How a job talks to the sweep that launched it: intermediate values and pruning.

Jobs call ``reporter = trial_reporter(cfg)`` once and ``reporter.report(value, step)`` after each
epoch or evaluation (``final=True`` with the last one, when they know it). Outside an Optuna
sweep the reporter records nothing and never prunes. Inside one, the sweeper tells the job which
trial it runs; ``report`` forwards the value to the study and raises ``optuna.TrialPruned`` when
the pruner says stop, but only where stopping saves work: never at a trial's first report (a
trial that reports once, such as a classical model's single fit, always completes) and never
at its final one. A pruner never discards a finished trial.

The sweeper passes the trial as JSON in the environment variable ``ASLEXP_TRIAL`` (set through
``hydra.job.env_set``, so it reaches the job in-process, in a submitit subprocess or on a Slurm
node alike, and stays out of the job's config):
``{"storage": SPEC, "study_name": ..., "trial_id": ..., "number": ..., "pruner": {...},
"heartbeat": SECONDS, "sampler": {...}}`` (the job's run.json records its study, number and
sampler). A job in the sweeper's own process uses the sweeper's live trial
object; any other process loads the study from the storage, and there:

* refuses to run a trial the study has finished already (its worker was gone before the job
  started, say a Slurm job that waited in the queue, and a resume gave the trial up and ran a
  replacement): :class:`TrialGivenUp`, recorded in run.json as the job's error, unless the
  folder holds the trial's run.json already (a requeued job in its trial's folder): that record,
  the one the study agrees with, is left as it is (:func:`refuse_given_up_trial`);
* refreshes the trial's heartbeat every ``heartbeat`` seconds while it runs, so that a sweep
  that lost the job's worker can tell, from any host, that the job still runs and wait for its
  result rather than run a replacement.
"""

from __future__ import annotations

import json
import logging
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

log = logging.getLogger(__name__)

ENV_VAR = "ASLEXP_TRIAL"

# Trials run by a sweeper in this very process, by (study name, trial number).
_LIVE_TRIALS: dict[tuple[str, int], Any] = {}


@dataclass(frozen=True)
class TrialContext:
    """What a job needs to find its trial: storage, study, trial and the study's pruner."""

    storage: str
    study_name: str
    trial_id: int
    number: int
    pruner: Mapping[str, Any] | None = None
    heartbeat: float | None = None  # seconds between the job's heartbeats (None: none)
    sampler: Mapping[str, Any] | None = None  # the settings that drew the trial (algorithms.sampler_settings)

    def to_json(self) -> str:
        data = {"storage": self.storage, "study_name": self.study_name,
                "trial_id": self.trial_id, "number": self.number,
                "pruner": dict(self.pruner or {})}
        if self.heartbeat:
            data["heartbeat"] = self.heartbeat
        if self.sampler:
            data["sampler"] = dict(self.sampler)
        return json.dumps(data, sort_keys=True, separators=(",", ":"))

    @classmethod
    def from_json(cls, text: str) -> "TrialContext":
        try:
            data = json.loads(text)
            return cls(storage=str(data["storage"]), study_name=str(data["study_name"]),
                       trial_id=int(data["trial_id"]), number=int(data["number"]),
                       pruner=data.get("pruner") or None,
                       heartbeat=float(data["heartbeat"]) if data.get("heartbeat") else None,
                       sampler=data.get("sampler") or None)
        except (ValueError, KeyError, TypeError) as err:
            raise ValueError(f"{ENV_VAR} is not a trial description ({err}): {text[:200]!r}") from err


class TrialGivenUp(RuntimeError):
    """The job's trial is finished in the study already: the job must not run it."""


# Heartbeats of the trials this process runs as a job (kept so they are started once).
_JOB_HEARTBEATS: dict[tuple[str, int], Any] = {}


def register_live_trial(study_name: str, trial: Any) -> None:
    _LIVE_TRIALS[(study_name, trial.number)] = trial


def unregister_live_trial(study_name: str, number: int) -> None:
    _LIVE_TRIALS.pop((study_name, number), None)


class NullReporter:
    """Reporter used when the job does not run as an Optuna trial."""

    active = False
    number: int | None = None

    def report(self, value: float, step: int, final: bool = False) -> None:
        return None


class TrialReporter:
    """Reports intermediate values of one Optuna trial and raises TrialPruned when told to."""

    active = True

    def __init__(self, trial: Any) -> None:
        self.trial = trial
        self.number: int = trial.number
        self.reports = 0

    def report(self, value: float, step: int, final: bool = False) -> None:
        """Record ``value`` at ``step``; raise optuna.TrialPruned if the pruner says stop.

        The first report and a ``final`` one are recorded but never pruned: there is no work
        left to save, only a finished result to lose.
        """
        import optuna

        value = float(value)
        if not math.isfinite(value):
            log.warning("trial %d: intermediate value at step %d is %s", self.number, step, value)
        self.trial.report(value, int(step))
        self.reports += 1
        if self.reports > 1 and not final and self.trial.should_prune():
            raise optuna.TrialPruned(f"trial {self.number} pruned at step {step} (value {value:.6g})")


def current_trial_context() -> TrialContext | None:
    text = os.environ.get(ENV_VAR)
    return TrialContext.from_json(text) if text else None


def _loaded_trial(context: TrialContext) -> tuple[Any, Any]:
    """The study (with its pruner) and the frozen trial of ``context``, from the storage."""
    import optuna

    from aslexp.tuning.algorithms import make_pruner
    from aslexp.tuning.storage import open_storage

    study = optuna.load_study(study_name=context.study_name, storage=open_storage(context.storage),
                              pruner=make_pruner(context.pruner))
    return study, study._storage.get_trial(context.trial_id)


def _refuse_if_finished(context: TrialContext, frozen: Any) -> None:
    if frozen.state.is_finished():
        from aslexp.tuning.worker import ATTR_ERROR

        why = frozen.user_attrs.get(ATTR_ERROR)
        raise TrialGivenUp(
            f"trial {context.number} of study {context.study_name!r} is already "
            f"{frozen.state.name.lower()} in the study" + (f" ({why})" if why else "") +
            ": its sweep gave it up before this job started; the job does not run it")


def refuse_given_up_trial() -> None:
    """Raise :class:`TrialGivenUp` when this job is a sweep's trial that the study has finished
    already: a job started again in its trial's folder (a requeued Slurm job) calls it before it
    writes anything there, so the folder keeps the record the study agrees with. Nothing to do
    outside a sweep, or for a trial the sweeper runs in this very process."""
    context = current_trial_context()
    if context is None or (context.study_name, context.number) in _LIVE_TRIALS:
        return
    _refuse_if_finished(context, _loaded_trial(context)[1])


def trial_reporter(cfg: Mapping[str, Any] | None = None) -> NullReporter | TrialReporter:
    """The reporter for this job: a real trial reporter inside a sweep, else a NullReporter.

    ``cfg`` is accepted for symmetry with the jobs (and future per-job options); the trial is
    identified by the ``ASLEXP_TRIAL`` environment variable the sweeper sets for the job.
    """
    context = current_trial_context()
    if context is None:
        return NullReporter()
    live = _LIVE_TRIALS.get((context.study_name, context.number))
    if live is not None:
        return TrialReporter(live)
    import optuna

    study, frozen = _loaded_trial(context)
    _refuse_if_finished(context, frozen)
    if context.heartbeat and (context.study_name, context.trial_id) not in _JOB_HEARTBEATS:
        from aslexp.tuning.worker import Heartbeat

        # Ends with the process (a daemon thread), or at the first beat after the trial ended.
        _JOB_HEARTBEATS[(context.study_name, context.trial_id)] = Heartbeat(
            study, context.trial_id, context.heartbeat).__enter__()
    return TrialReporter(optuna.trial.Trial(study, context.trial_id))
