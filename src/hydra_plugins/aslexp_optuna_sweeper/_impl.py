"""The Hydra side of aslexp's Optuna sweeper: config in, one job per trial out.

Everything Hydra-specific lives here (search-space parsing with Hydra's override grammar, the
launcher, spawning worker processes); the loop and its guarantees live in
:mod:`aslexp.tuning.worker`, which knows nothing of Hydra.
"""

from __future__ import annotations

import logging
import os
import re
import signal
import subprocess
import sys
import time
import traceback
from pathlib import Path
from typing import Any

import optuna
from hydra.core.hydra_config import HydraConfig
from hydra.core.plugins import Plugins
from hydra.core.utils import JobReturn, JobStatus
from hydra.plugins.sweeper import Sweeper
from hydra.types import HydraContext, TaskFunction
from omegaconf import DictConfig, ListConfig, OmegaConf, open_dict

from aslexp.runs.logfmt import install_float_rounding, quiet_log_write_errors
from aslexp.tuning.algorithms import (ATTR_SAMPLER, AlgorithmSpecError, make_pruner, make_sampler,
                                      record_sampler_settings, sampler_settings)
from aslexp.tuning.context import (
    ENV_VAR,
    TrialContext,
    register_live_trial,
    unregister_live_trial,
)
from aslexp.tuning.storage import JournalWriteError, StorageError, redact, resolve_spec, silence_optuna
from aslexp.tuning.study import (
    StudyError,
    SweepInfo,
    create_or_resume_study,
    resolve_study_name,
    study_home,
)
from aslexp.tuning.worker import (
    ATTR_OVERRIDES,
    ATTR_RUN_DIR,
    INTERRUPTED,
    DirectionMismatchError,
    LaunchRefused,
    Outcome,
    WorkerSettings,
    budget_complete,
    read_run_record,
    register_sweep_dir,
    run_worker,
    state_counts,
)
from hydra_plugins.aslexp_optuna_sweeper._space import (
    SearchSpace,
    SearchSpaceError,
    parse_search_space,
    quote,
)

log = logging.getLogger(__name__)

# Overrides the sweeper sets itself on the worker processes it spawns.
_SPAWN_KEYS = ("hydra.sweep.dir", "hydra.sweeper.n_workers", "hydra.sweeper.worker_index",
               "hydra.job.name", "hydra.sweeper.check_search_space")
# Slurm states of a job that ended without a result because it was stopped from outside (not
# because the trial failed): its trial is interrupted and runs again.
_STOPPED_FROM_OUTSIDE = ("CANCELLED", "PREEMPTED", "NODE_FAIL", "BOOT_FAIL", "REQUEUED",
                         "DEADLINE")
# Seconds the sweeper waits for its workers after Ctrl-C before it signals them itself.
_CHILD_GRACE = 5.0


class SweeperImpl(Sweeper):
    """Optuna sweeper with a persistent study, resume, pruning and asynchronous workers."""

    def __init__(
        self,
        direction: str = "maximize",
        n_trials: int = 20,
        n_workers: int = 1,
        storage: str | None = None,
        study_name: str | None = None,
        params: DictConfig | dict | None = None,
        sampler: DictConfig | dict | None = None,
        pruner: DictConfig | dict | None = None,
        heartbeat_interval: float = 30.0,
        grace_period: float = 600.0,
        check_search_space: bool = True,
        worker_index: int = 0,
        continue_study: bool = False,
        enqueue: Any = None,
    ) -> None:
        self.direction = str(direction).lower()
        self.n_trials = int(n_trials)
        self.n_workers = int(n_workers)
        self.storage = storage
        self.study_name = study_name
        self.params = _plain(params) or {}
        self.sampler_spec = _plain(sampler) or {"name": "tpe"}
        self.pruner_spec = _plain(pruner) or {"name": "none"}
        self.heartbeat_interval = float(heartbeat_interval)
        self.grace_period = float(grace_period)
        self.check_search_space = bool(check_search_space)
        self.worker_index = int(worker_index)
        self.continue_study = bool(continue_study)
        self.enqueue = _plain(enqueue) or []  # resolved: ${...} reads the job's config (its gains)
        if self.direction not in ("maximize", "minimize"):
            raise ValueError(f"hydra.sweeper.direction must be maximize or minimize, got {direction!r}")
        if self.n_trials < 1:
            raise ValueError(f"hydra.sweeper.n_trials must be >= 1, got {n_trials}")
        if self.n_workers < 1:
            raise ValueError(f"hydra.sweeper.n_workers must be >= 1, got {n_workers}")

    def setup(self, *, hydra_context: HydraContext, task_function: TaskFunction,
              config: DictConfig) -> None:
        self.config = config
        self.hydra_context = hydra_context
        self.task_function = task_function
        self.launcher = Plugins.instance().instantiate_launcher(
            config=config, hydra_context=hydra_context, task_function=task_function
        )

    # ------------------------------------------------------------------ the sweep

    def sweep(self, arguments: list[str]) -> None:
        try:
            self._sweep(arguments)
        except JournalWriteError as err:  # a full disk: the job of the machine, not bad input
            print(f"aslexp {self.config.hydra.job.name}: {err}", file=sys.stderr, flush=True)
            raise SystemExit(1) from err
        except (SearchSpaceError, StudyError, StorageError, AlgorithmSpecError,
                DirectionMismatchError, LaunchRefused) as err:
            # Bad input, not a bug: say what is wrong in one line, without a traceback.
            print(f"aslexp {self.config.hydra.job.name}: {err}", file=sys.stderr, flush=True)
            raise SystemExit(2) from err

    def _sweep(self, arguments: list[str]) -> None:
        silence_optuna()
        install_float_rounding()
        quiet_log_write_errors()
        space = parse_search_space(self.params, list(arguments))
        first_points = _enqueued_points(self.enqueue, space)  # checked before anything is written
        sweep_dir = Path(str(self.config.hydra.sweep.dir)).resolve()
        spec = resolve_spec(self.storage, sweep_dir)
        job_name = str(self.config.hydra.job.name)
        study_name = resolve_study_name(spec, self.study_name, job_name)
        if self.worker_index == 0 and self.check_search_space:
            self._check_search_space(space)

        study = create_or_resume_study(spec, study_name, self.direction,
                                       pruner=make_pruner(self.pruner_spec))
        # Seeded: each trial draws from its own stream, chosen by its number (never shared).
        study.sampler = make_sampler(self.sampler_spec)
        self.sampler_settings = sampler = sampler_settings(self.sampler_spec, study)
        if self.worker_index == 0:
            record_sampler_settings(study, sampler)
        existing = len(study.get_trials(deepcopy=False))
        label = f"worker {self.worker_index}"
        # The folder's first study keeps it; another study gets studies/<name>/ (never a shared
        # trial folder). Worker 0 (re)writes the study's sweep.json.
        self.home = study_home(sweep_dir, SweepInfo(
            job=job_name, study_name=study_name, storage=redact(spec),
            direction=self.direction, n_trials=self.n_trials, params=space.sources,
            fixed_overrides=space.fixed, sampler=self.sampler_spec, sampler_settings=sampler,
            pruner=self.pruner_spec,
            task_module=_task_module(self.task_function, strict=False),
            command=" ".join([Path(sys.argv[0]).name, *sys.argv[1:]]),
        ), write=self.worker_index == 0, continue_study=self.continue_study)
        self.sweep_dir = sweep_dir
        register_sweep_dir(study_name, self.home)  # trial folders are recorded relative to it
        if self.worker_index == 0 and not existing:  # a new study: its first points, once
            for point in first_points:
                study.enqueue_trial(point)
        if self.worker_index == 0:
            if self.home != sweep_dir:
                log.info("%s belongs to another study (its sweep.json): study %r lives in %s",
                         sweep_dir, study_name, self.home)
            log.info("sweep folder %s: study %r in %s, %s, budget %d trials (%d exist), "
                     "%d worker(s), sampler %s, pruner %s", self.home, study_name, redact(spec),
                     self.direction, self.n_trials, existing, self.n_workers,
                     self.sampler_spec.get("name"), self.pruner_spec.get("name"))

        children = self._spawn_workers(sweep_dir) if self.n_workers > 1 else []
        settings = WorkerSettings(storage_spec=spec, study_name=study_name,
                                  n_trials=self.n_trials, grace_period=self.grace_period,
                                  heartbeat_interval=self.heartbeat_interval, worker_label=label)
        try:
            summary = run_worker(
                study, space.distributions, settings,
                launch=lambda trial: self._launch(study, trial, space, spec, study_name),
                on_asked=lambda trial: (
                    study._storage.set_trial_user_attr(trial._trial_id, ATTR_OVERRIDES,
                                                       space.overrides_for(trial.params)),
                    study._storage.set_trial_user_attr(trial._trial_id, ATTR_SAMPLER, sampler)),
            )
        except KeyboardInterrupt:
            _stop_children(children, grace=_CHILD_GRACE)
            raise
        except BaseException:
            _stop_children(children, grace=0.0)
            raise
        self._finish(study, study_name, label, summary, _wait_children(children))

    def _finish(self, study: optuna.Study, study_name: str, label: str, summary, failed_children: dict) -> None:
        """The sweep's last lines (worker 0: the study and its best trial); an error when a spawned
        worker ended abnormally and the budget is not complete."""
        log.info("%s ran %d trial(s): %s", label, len(summary.trials), dict(summary.states))
        if self.worker_index == 0:
            counts = state_counts(study.get_trials(deepcopy=False))
            log.info("study %r now: %s (sweep folder %s)", study_name, dict(sorted(counts.items())),
                     self.home)
            if counts.get("complete"):
                best = study.best_trial
                log.info("best trial %d: value %.6g, params %s", best.number, best.value, best.params)
        if failed_children:
            gone = ", ".join(f"pid {pid} (exit {code})" for pid, code in failed_children.items())
            if not budget_complete(study, self.n_trials):
                raise RuntimeError(f"sweep worker process(es) {gone} ended abnormally and the "
                                   f"study's budget of {self.n_trials} trials is not complete: run "
                                   "the same command to resume it")
            # The others settled the lost worker's trial and ran its point again: the work is done.
            log.warning("sweep worker process(es) %s ended abnormally; the study's budget of %d "
                        "trials is complete all the same", gone, self.n_trials)

    # ------------------------------------------------------------------ one trial

    def _launch(self, study: optuna.Study, trial: optuna.trial.Trial, space: SearchSpace,
                spec: str, study_name: str) -> Outcome:
        context = TrialContext(storage=spec, study_name=study_name, trial_id=trial._trial_id,
                               number=trial.number, pruner=self.pruner_spec,
                               heartbeat=self.heartbeat_interval or None, sampler=self.sampler_settings)
        subdir = self._claim_trial_folder(trial.number, space.overrides_for(trial.params))
        run_dir = str(self.sweep_dir / subdir)
        # Known before the job starts: a trial lost with its worker is marked in its run.json too.
        # Recorded relative to the study's home (a moved or copied folder finds its trials).
        study._storage.set_trial_user_attr(trial._trial_id, ATTR_RUN_DIR,
                                           os.path.relpath(run_dir, self.home))
        overrides = [*space.overrides_for(trial.params),
                     f"hydra.sweep.subdir={quote(subdir)}",
                     f"++hydra.job.env_set.{ENV_VAR}={quote(context.to_json())}"]
        register_live_trial(study_name, trial)
        try:
            returns = self.launcher.launch([overrides], initial_job_idx=trial.number)
        except Exception as err:  # noqa: BLE001 - a cluster job that ended without a result
            state = _stopped_state(err)
            if state is None:
                raise
            return Outcome(INTERRUPTED, error=f"its cluster job ended {state} (stopped from "
                           "outside: scancel, preemption or a node failure)", run_dir=run_dir)
        finally:
            unregister_live_trial(study_name, trial.number)
        return outcome_of(returns[0], trial.number)

    def _claim_trial_folder(self, number: int, overrides: list[str]) -> str:
        """The trial's run folder (relative to the sweep dir), created now so it is its alone.

        ``hydra.sweep.subdir`` as the job's config says (trial number as ``hydra.job.num``),
        under the study's home; should that folder hold anything already (a study whose
        storage was deleted, a subdir without the number), ``-2``, ``-3``, ... is appended.
        """
        subdir = _numbered_subdir(self.config, number, overrides)
        if subdir is None:  # the name reads the trial's config: compose it
            config = self.hydra_context.config_loader.load_sweep_config(self.config, list(overrides))
            with open_dict(config):
                config.hydra.job.id = number
                config.hydra.job.num = number
            saved = HydraConfig.instance().cfg
            try:
                HydraConfig.instance().set_config(config)
                subdir = str(OmegaConf.select(config, "hydra.sweep.subdir"))
            finally:
                HydraConfig.instance().cfg = saved
        base = (self.home / subdir).relative_to(self.sweep_dir)
        candidate, k = base, 1
        while True:
            folder = self.sweep_dir / candidate
            try:
                folder.mkdir(parents=True, exist_ok=False)
                return str(candidate)
            except FileExistsError:
                k += 1
                candidate = base.with_name(f"{base.name}-{k}")

    def _check_search_space(self, space: SearchSpace) -> None:
        """Compose the job's config at sample points: a typo fails here, before any trial."""
        points = [space.sample_point()]
        for name, dist in space.distributions.items():
            if isinstance(dist, optuna.distributions.CategoricalDistribution):
                points += [{**points[0], name: choice} for choice in dist.choices[1:]]
        for point in points[:64]:
            overrides = space.overrides_for(point)
            try:
                self.hydra_context.config_loader.load_sweep_config(self.config, overrides)
            except Exception as err:  # noqa: BLE001 - Hydra raises several exception types
                raise SearchSpaceError(
                    f"the search space does not fit the job's config (no trial was started): "
                    f"composing with {overrides} failed: {type(err).__name__}: {err}"
                ) from err

    # ------------------------------------------------------------------ parallel workers

    def _spawn_workers(self, sweep_dir: Path) -> list[subprocess.Popen]:
        """Start workers 1..n-1 as processes running this same sweep (each with n_workers=1)."""
        module = _task_module(self.task_function)
        name = self.task_function.__name__
        code = f"import importlib; importlib.import_module({module!r}).{name}()"
        hydra_cfg = self.config.hydra
        inherited = [o for o in [*hydra_cfg.overrides.hydra, *hydra_cfg.overrides.task]
                     if o.split("=", 1)[0].lstrip("+~") not in _SPAWN_KEYS]
        config_dirs = [s.path for s in hydra_cfg.runtime.config_sources
                       if s.provider == "command-line"]
        head = [sys.executable, "-c", code, "--multirun",
                "--config-name", str(hydra_cfg.job.config_name)]
        for path in config_dirs:
            head += ["--config-dir", str(path)]
        children = []
        for index in range(1, self.n_workers):
            argv = [*head, *inherited, f"hydra.sweep.dir={quote(str(sweep_dir))}",
                    "hydra.sweeper.n_workers=1", f"hydra.sweeper.worker_index={index}",
                    f"hydra.job.name={quote(str(hydra_cfg.job.name))}",
                    "hydra.sweeper.check_search_space=false"]
            children.append(subprocess.Popen(argv, env={**os.environ}))
            log.info("started sweep worker %d (pid %d)", index, children[-1].pid)
        return children


_NUMBER_ONLY = re.compile(r"\$\{hydra\.job\.(?:num|id)\}")


def _numbered_subdir(config: DictConfig, number: int, overrides: list[str]) -> str | None:
    """``hydra.sweep.subdir`` when it names the trial by its number alone (``${hydra.job.num}``,
    the imitation and tuning jobs' default), without composing the trial's config: a composition
    costs about 0.2 s, a third of a near-empty trial. None when the name reads anything else, or a
    trial's overrides touch Hydra's own config."""
    raw = OmegaConf.to_container(config.hydra.sweep, resolve=False).get("subdir")
    if not isinstance(raw, str) or any(o.lstrip("+~").startswith("hydra.") for o in overrides):
        return None
    name = _NUMBER_ONLY.sub(str(number), raw)
    return None if "${" in name else name


def outcome_of(ret: JobReturn, number: int) -> Outcome:
    """Turn a Hydra JobReturn into an Outcome (value, pruned, or failure with its error)."""
    run_dir = None
    if ret.hydra_cfg is not None:
        run_dir = str(ret.hydra_cfg.hydra.runtime.output_dir)
    main = _run_record(run_dir).get("main_metric") or {}
    goal, metric = main.get("goal"), main.get("name")
    result = ret._return_value
    if ret.status == JobStatus.COMPLETED:
        try:
            value = float(result)
        except (TypeError, ValueError):
            return Outcome("failed", error=f"the job returned {result!r}; a sweep needs the job "
                           "to return its main metric as a number", run_dir=run_dir)
        recorded = _run_record(run_dir)
        if recorded.get("status") == "failed":  # the job caught its error and returned NaN
            return Outcome("failed", value=value, error=recorded.get("error") or "failed",
                           run_dir=run_dir)
        return Outcome("complete", value=value, run_dir=run_dir, goal=goal, metric=metric)
    if isinstance(result, optuna.TrialPruned):
        return Outcome("pruned", error=str(result), run_dir=run_dir)
    if isinstance(result, BaseException):
        log.error("trial %d failed:\n%s", number, "".join(traceback.format_exception(result)))
        text = "".join(traceback.format_exception_only(type(result), result)).strip()
        return Outcome("failed", error=text, run_dir=run_dir)
    return Outcome("failed", error=f"job ended with status {ret.status}", run_dir=run_dir)


def _run_record(run_dir: str | None) -> dict[str, Any]:
    """The job's run.json ({} when there is none or it is unreadable)."""
    return read_run_record(run_dir)


def _stopped_state(err: BaseException) -> str | None:
    """The Slurm state of a submitit job that ended without a result because it was stopped
    from outside (e.g. ``CANCELLED by 0``); None for any other error."""
    if type(err).__name__ != "UncompletedJobError":
        return None
    match = re.search(r"state: ([A-Z_]+)", str(err))
    if match and match.group(1) in _STOPPED_FROM_OUTSIDE:
        return match.group(1)
    return None


def _plain(node: Any) -> Any:
    if isinstance(node, (DictConfig, ListConfig)):
        return OmegaConf.to_container(node, resolve=True)
    return dict(node) if isinstance(node, dict) else node


def _enqueued_points(points: Any, space: SearchSpace) -> list[dict[str, Any]]:
    """``hydra.sweeper.enqueue`` checked: a list of {swept parameter: value}."""
    if not isinstance(points, list):
        raise SearchSpaceError(f"hydra.sweeper.enqueue: expected a list of {{parameter: value}}, got {points!r}")
    for i, point in enumerate(points):
        if not isinstance(point, dict) or not point:
            raise SearchSpaceError(f"hydra.sweeper.enqueue[{i}]: expected {{parameter: value}}, got {point!r}")
        unknown = sorted(set(point) - set(space.distributions))
        if unknown:
            raise SearchSpaceError(f"hydra.sweeper.enqueue[{i}]: {', '.join(unknown)} not swept "
                                   f"(swept: {', '.join(sorted(space.distributions)) or 'nothing'})")
    return points


def _task_module(task_function: TaskFunction, strict: bool = True) -> str | None:
    """The importable module of the task function (``python -m X`` runs it as __main__)."""
    module = task_function.__module__
    if module == "__main__":
        spec = getattr(sys.modules["__main__"], "__spec__", None)
        if spec is None or not spec.name:
            if not strict:
                return None
            raise RuntimeError("n_workers > 1 needs the job started as a module "
                               "(aslexp JOB ... or python -m aslexp.jobs.JOB ...)")
        module = spec.name
    return module


def _stop_children(children: list[subprocess.Popen], grace: float, timeout: float = 30.0) -> None:
    """Stop the spawned workers; each records its running trial as interrupted.

    After Ctrl-C in a terminal every worker got the SIGINT too: they get ``grace`` seconds to
    record their trial and exit on their own. Those still running then get SIGINT (SIGTERM,
    and finally SIGKILL after ``timeout``; a killed worker's trial is found by the next start).
    """
    deadline = time.monotonic() + grace
    for child in children:
        try:
            child.wait(timeout=max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            pass
    for child in children:
        if child.poll() is None:
            child.send_signal(signal.SIGINT if grace > 0 else signal.SIGTERM)
    deadline = time.monotonic() + timeout
    for child in children:
        try:
            child.wait(timeout=max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            child.kill()
            child.wait()


def _wait_children(children: list[subprocess.Popen]) -> dict[int, int]:
    failed = {}
    for child in children:
        code = child.wait()
        if code != 0:
            failed[child.pid] = code
    return failed
