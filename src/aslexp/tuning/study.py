"""Studies of a sweep: create or resume one, describe it in sweep.json, and find it again.

A sweep directory holds ``sweep.json`` (written by the sweeper: job, study name, storage without
password, direction, budget, search space, fixed overrides), the default journal storage
``optuna.journal``, and one run directory per trial, named by trial number (through
``hydra.sweep.subdir``). The folder belongs to the first study that ran in it; another study
run into the same folder (``hydra.sweeper.study_name=other``) gets a home of its own,
``studies/<name>/``, with its own sweep.json and trial folders, so that no two trials ever
share a folder: ``aslexp sweep status SWEEP_DIR/studies/other`` shows it.

A study is one sweep: a command that would continue it with another job, search space or fixed
overrides than its sweep.json records is refused (:func:`sweep_differences`), with what differs
and the two ways on: a study of its own beside it (``hydra.sweeper.study_name=NEW``), or this
study continued with the new settings (``hydra.sweeper.continue_study=true``).
"""

from __future__ import annotations

import datetime as _dt
import logging
import os
import re
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import optuna
from optuna.trial import FrozenTrial, TrialState

from aslexp.files import read_json, write_json
from aslexp.tuning.storage import (
    default_storage,
    file_lock,
    is_database_url,
    open_storage,
    redact,
    resolve_spec,
    study_names,
)
from aslexp.tuning.worker import (
    ATTR_ADOPTED,
    ATTR_ERROR,
    ATTR_OVERRIDES,
    ATTR_RUN_DIR,
    INTERRUPTED,
    judge_running_trial,
    register_sweep_dir,
    run_dir_of,
    state_counts,
)

log = logging.getLogger(__name__)

SWEEP_FILE = "sweep.json"
STUDIES_DIR = "studies"  # homes of the further studies of a sweep folder
# The sweeper key that continues a study with another search space or fixed overrides than it was run with.
CONTINUE_KEY = "hydra.sweeper.continue_study"


class StudyError(RuntimeError):
    """A study that cannot be created, resumed or found, with what to do about it."""


@dataclass
class SweepInfo:
    """What sweep.json records about a sweep."""

    job: str
    study_name: str
    storage: str                      # redacted: no password
    direction: str
    n_trials: int
    params: dict[str, str] = field(default_factory=dict)
    fixed_overrides: list[str] = field(default_factory=list)
    sampler: dict[str, Any] = field(default_factory=dict)
    # every setting the sampler ran with, Optuna's defaults included (algorithms.sampler_settings)
    sampler_settings: dict[str, Any] = field(default_factory=dict)
    pruner: dict[str, Any] = field(default_factory=dict)
    task_module: str | None = None    # e.g. aslexp.jobs.recognize (python -m form of the job)
    command: str | None = None
    created: str | None = None
    updated: str | None = None

    @classmethod
    def from_saved(cls, data: Mapping[str, Any]) -> "SweepInfo":
        """A sweep.json aslexp wrote (keys of a newer version ignored): a record, not configuration."""
        known = set(cls.__dataclass_fields__)
        return cls(**{k: v for k, v in data.items() if k in known})


def _now() -> str:
    return _dt.datetime.now().astimezone().isoformat(timespec="seconds")


def write_sweep_info(sweep_dir: str | os.PathLike, info: SweepInfo,
                     root: str | os.PathLike | None = None) -> None:
    """Write ``sweep_dir/sweep.json``. A journal inside ``root`` (the sweep folder; default
    ``sweep_dir``) is recorded relative to ``sweep_dir``: a moved or copied sweep folder reads
    its own journal, never the original's."""
    path = Path(sweep_dir) / SWEEP_FILE
    path.parent.mkdir(parents=True, exist_ok=True)
    if info.storage and not is_database_url(info.storage) and Path(info.storage).is_absolute():
        journal, top = Path(info.storage).resolve(), Path(root or sweep_dir).resolve()
        if journal.is_relative_to(top):
            info.storage = os.path.relpath(journal, Path(sweep_dir).resolve())
    if path.exists():
        try:
            info.created = read_json(path).get("created") or info.created
        except (OSError, ValueError):
            pass
    info.created = info.created or _now()
    info.updated = _now()
    write_json(path, asdict(info))


def read_sweep_info(sweep_dir: str | os.PathLike) -> SweepInfo | None:
    path = Path(sweep_dir) / SWEEP_FILE
    if not path.exists():
        return None
    try:
        data = read_json(path)
    except ValueError as err:
        raise ValueError(f"{path}: not valid JSON ({err})") from None
    if not isinstance(data, dict):
        raise ValueError(f"{path}: a JSON {type(data).__name__}, expected an object")
    return SweepInfo.from_saved(data)


def safe_name(name: str) -> str:
    """A study name as a folder name."""
    return re.sub(r"[^A-Za-z0-9_.=-]+", "_", name).strip("._") or "study"


def _canonical(text: str) -> str:
    """An override's text without the spaces outside quotes (``interval(-1, 1)`` is
    ``interval(-1,1)``)."""
    quoted = r"('(?:[^'\\]|\\.)*'|\"(?:[^\"\\]|\\.)*\")"
    return "".join(part if i % 2 else re.sub(r"\s+", "", part)
                   for i, part in enumerate(re.split(quoted, text)))


def _by_key(overrides: list[str]) -> dict[str, list[str]]:
    keys: dict[str, list[str]] = {}
    for override in overrides:
        key = override.split("=", 1)[0].strip().lstrip("+~")
        keys.setdefault(key, []).append(_canonical(override))
    return {key: sorted(values) for key, values in keys.items()}


def sweep_differences(recorded: SweepInfo, info: SweepInfo) -> list[str]:
    """What makes ``info`` another sweep than the one ``recorded`` describes: its job, a swept
    parameter (added, gone, another range) or a fixed override (added, gone, another value).
    The budget, workers, sampler and pruner may change between the runs of one study."""
    differences = []
    if recorded.job and info.job != recorded.job:
        differences.append(f"job {info.job} here, {recorded.job} there")
    for name in sorted(set(recorded.params) | set(info.params)):
        mine, theirs = info.params.get(name), recorded.params.get(name)
        if theirs is None:
            differences.append(f"{name}={mine} is swept here, not there")
        elif mine is None:
            differences.append(f"{name} is not swept here ({theirs} there)")
        elif _canonical(str(mine)) != _canonical(str(theirs)):
            differences.append(f"{name}={mine} here, {theirs} there")
    mine, theirs = _by_key(info.fixed_overrides), _by_key(recorded.fixed_overrides)
    for key in sorted(set(mine) | set(theirs)):
        if key not in theirs:
            differences.append(f"fixed {' '.join(mine[key])} is new here")
        elif key not in mine:
            differences.append(f"fixed {' '.join(theirs[key])} is not given here")
        elif mine[key] != theirs[key]:
            differences.append(f"fixed {' '.join(mine[key])} here, {' '.join(theirs[key])} there")
    return differences


def study_home(sweep_dir: str | os.PathLike, info: SweepInfo, write: bool = True,
               continue_study: bool = False) -> Path:
    """The folder of this study's sweep.json and trials; registers the study there.

    The sweep folder itself for its first study, ``<sweep dir>/studies/<name>`` for any other.
    Decided under a lock, so two studies started together into a new folder do not both take
    it. ``write``: (re)write the study's sweep.json (worker 0 does; other workers only when
    it is missing).

    A study whose sweep.json records another job, search space or fixed overrides than ``info``
    is not continued (:class:`StudyError`, nothing written) unless ``continue_study``
    (``hydra.sweeper.continue_study=true``).
    """
    sweep_dir = Path(sweep_dir)
    sweep_dir.mkdir(parents=True, exist_ok=True)
    with file_lock(sweep_dir / ".sweep.lock"):
        first = read_sweep_info(sweep_dir)
        if first is None or first.study_name == info.study_name:
            home = sweep_dir
        else:
            home = sweep_dir / STUDIES_DIR / safe_name(info.study_name)
        recorded = first if home == sweep_dir else read_sweep_info(home)
        differences = sweep_differences(recorded, info) if recorded is not None else []
        if differences and not continue_study:
            raise StudyError(
                f"{home} holds study {info.study_name!r} of another sweep (its {SWEEP_FILE} "
                f"differs: {'; '.join(differences)}); nothing was changed: run this one as a "
                f"study of its own with hydra.sweeper.study_name=NEW (its home: "
                f"{sweep_dir}/{STUDIES_DIR}/NEW) or another hydra.sweep.dir, or set "
                f"{CONTINUE_KEY}=true to continue study {info.study_name!r} with this sweep's settings")
        if differences:
            log.warning("study %r in %s is continued with other settings (%s=true): %s",
                        info.study_name, home, CONTINUE_KEY, "; ".join(differences))
        if write or not (home / SWEEP_FILE).exists():
            write_sweep_info(home, info, root=sweep_dir)
    return home


def other_studies(sweep_dir: str | os.PathLike) -> list[Path]:
    """The homes of the further studies run into ``sweep_dir``."""
    root = Path(sweep_dir) / STUDIES_DIR
    return sorted(p for p in root.glob("*") if (p / SWEEP_FILE).is_file()) if root.is_dir() else []


def resolve_study_name(spec: str, requested: str | None, default: str) -> str:
    """The study to use: as requested; in a journal file, its only study or ``default``.

    A database is shared by many sweeps, so there the name must be given explicitly.
    """
    if requested:
        return str(requested)
    if is_database_url(spec):
        raise StudyError(
            f"storage {redact(spec)} is a database that many sweeps can share: name this sweep's "
            "study with hydra.sweeper.study_name=NAME (the same name in every worker)"
        )
    if not Path(spec).exists() or Path(spec).stat().st_size == 0:
        return default
    names = study_names(open_storage(spec))
    if len(names) == 1:
        return names[0]
    if not names:
        return default
    if default in names:
        return default
    raise StudyError(f"{spec} holds several studies {names}: pick one with hydra.sweeper.study_name")


def create_or_resume_study(spec: str, study_name: str, direction: str,
                           sampler: optuna.samplers.BaseSampler | None = None,
                           pruner: optuna.pruners.BasePruner | None = None) -> optuna.Study:
    """Create the study, or load it if it exists (checking it optimises the same direction)."""
    direction = str(direction).lower()
    if direction not in ("maximize", "minimize"):
        raise StudyError(f"hydra.sweeper.direction must be maximize or minimize, got {direction!r}")
    storage = open_storage(spec)
    # Loaded, not "created if missing": a resume, or a sweep refused after this, writes nothing
    # (in a journal, a create of an existing study is still an append).
    if study_name in study_names(storage):
        study = optuna.load_study(study_name=study_name, storage=storage, sampler=sampler,
                                  pruner=pruner)
    else:
        study = optuna.create_study(storage=storage, study_name=study_name, direction=direction,
                                    sampler=sampler, pruner=pruner, load_if_exists=True)
    if len(study.directions) != 1 or study.direction.name.lower() != direction:
        stored = [d.name.lower() for d in study.directions]
        raise StudyError(
            f"study {study_name!r} in {redact(spec)} optimises {stored}, but this sweep asks to "
            f"{direction}: use another hydra.sweep.dir / study_name, or the stored direction"
        )
    return study


def open_sweep(sweep_dir: str | os.PathLike, storage: str | None = None,
               study_name: str | None = None) -> tuple[optuna.Study, SweepInfo | None]:
    """Load the study of a sweep directory (for status, best, report, dashboard).

    ``study_name`` other than the folder's own study: that study's home under studies/.
    """
    sweep_dir = Path(sweep_dir)
    info_dir = sweep_dir  # the folder of the sweep.json read: its storage path is relative to it
    try:
        info = read_sweep_info(sweep_dir)
        if study_name and info is not None and info.study_name != study_name:
            home = sweep_dir / STUDIES_DIR / safe_name(study_name)
            own = read_sweep_info(home)
            info, info_dir = (own, home) if own is not None else (info, info_dir)
    except (OSError, ValueError) as err:  # a damaged sweep.json: one line, no traceback
        raise StudyError(f"{' '.join(str(err).split())}; pass --storage and --study to read the study "
                         "without it") from None
    if storage is None:
        storage = os.environ.get("ASLEXP_OPTUNA_STORAGE")
        if storage is None and info is not None:
            storage = info.storage  # a journal inside the folder is recorded relative to it
            if not is_database_url(storage) and not Path(storage).is_absolute():
                storage = str(info_dir / storage)
    if storage is None:
        if not (sweep_dir / "optuna.journal").exists():
            raise StudyError(f"{sweep_dir} is not a sweep directory: no {SWEEP_FILE} and no "
                             "optuna.journal (pass --storage to read a study elsewhere)")
        storage = default_storage(sweep_dir)
    spec = resolve_spec(storage, sweep_dir)
    if not is_database_url(spec) and not Path(spec).exists():
        raise StudyError(f"journal file {spec} of sweep {sweep_dir} does not exist")
    backend = open_storage(spec, read_only=True)  # the tools write nothing, lock nothing
    names = study_names(backend)
    name = study_name or (info.study_name if info else None)
    if name is None:
        if len(names) != 1:
            raise StudyError(f"{redact(spec)} holds studies {names}: pass --study NAME")
        name = names[0]
    if name not in names:
        raise StudyError(f"no study {name!r} in {redact(spec)} (it holds {names})")
    register_sweep_dir(name, info_dir)  # trial folders are recorded relative to the study's home
    return optuna.load_study(study_name=name, storage=backend), info


# --------------------------------------------------------------------------- summaries


def trial_summary(trial: FrozenTrial, study_name: str | None = None) -> dict[str, Any]:
    return {
        "number": trial.number,
        "state": trial.state.name.lower(),
        "value": trial.value,
        "params": dict(trial.params),
        "error": trial.user_attrs.get(ATTR_ERROR),
        "adopted": trial.user_attrs.get(ATTR_ADOPTED),
        "run_dir": run_dir_of(trial.user_attrs.get(ATTR_RUN_DIR), study_name),
        "overrides": list(trial.user_attrs.get(ATTR_OVERRIDES) or []),
        "started": trial.datetime_start.isoformat(timespec="seconds") if trial.datetime_start else None,
        "finished": trial.datetime_complete.isoformat(timespec="seconds") if trial.datetime_complete else None,
        "last_step": trial.last_step,
    }


def status_summary(study: optuna.Study, info: SweepInfo | None,
                   sweep_dir: str | os.PathLike | None = None) -> dict[str, Any]:
    """Counts by state against the budget, the best trial; ``other_studies``: further studies
    in ``sweep_dir``. Running trials whose worker (on this machine) is gone, as the next worker
    will settle them (:func:`aslexp.tuning.worker.judge_running_trial`): ``lost`` (to be marked
    interrupted), ``orphans_finished`` (their job finished: its result will be adopted),
    ``orphans_running`` (their job still runs: waited for, then adopted). Nothing is changed."""
    trials = study.get_trials(deepcopy=False)
    counts = state_counts(trials)
    verdicts = [judge_running_trial(t, grace_period=float("inf"), study_name=study.study_name)
                for t in trials if t.state == TrialState.RUNNING]
    lost = sum(1 for v in verdicts if v.action == INTERRUPTED)
    finished = sum(1 for v in verdicts if v.action == "adopt")
    orphans = sum(1 for v in verdicts if v.action == "wait")
    summary: dict[str, Any] = {
        "study_name": study.study_name,
        "direction": study.direction.name.lower(),
        "n_trials_budget": info.n_trials if info else None,
        "trials": len(trials),
        "counts": dict(sorted(counts.items())),
        "lost": lost,
        "orphans_finished": finished,
        "orphans_running": orphans,
        "adopted": [t.number for t in trials if t.user_attrs.get(ATTR_ADOPTED)],
        "other_studies": [str(p) for p in other_studies(sweep_dir)] if sweep_dir else [],
        "best": None,
    }
    summary["failed"] = [trial_summary(t, study.study_name) for t in trials
                         if t.state == TrialState.FAIL and t.user_attrs.get(ATTR_ERROR)]
    completed = [t for t in trials if t.state == TrialState.COMPLETE]
    if completed:
        summary["best"] = trial_summary(study.best_trial, study.study_name)
    return summary
