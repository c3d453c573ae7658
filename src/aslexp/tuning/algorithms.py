"""Samplers and pruners from plain specs: ``{"name": "median", "n_startup_trials": 5, ...}``.

The specs come from conf/hydra/sweeper/{sampler,pruner}/*.yaml; every other key is passed to the
Optuna class as a keyword argument, so any option Optuna documents can be set from config.
A job process rebuilds the study's pruner from the same spec (see :mod:`aslexp.tuning.context`).
"""

from __future__ import annotations

import hashlib
import inspect
import logging
from collections.abc import Mapping, Sequence
from typing import Any

import optuna
from optuna.distributions import BaseDistribution
from optuna.samplers import BaseSampler
from optuna.trial import FrozenTrial, TrialState

log = logging.getLogger(__name__)

SAMPLERS = {
    "tpe": "TPESampler",
    "random": "RandomSampler",
    "cmaes": "CmaEsSampler",
    "qmc": "QMCSampler",
    "gp": "GPSampler",
    "nsgaii": "NSGAIISampler",
}

PRUNERS = {
    "median": "MedianPruner",
    "percentile": "PercentilePruner",
    "hyperband": "HyperbandPruner",
    "successive_halving": "SuccessiveHalvingPruner",
    "threshold": "ThresholdPruner",
    "none": "NopPruner",
}


class AlgorithmSpecError(ValueError):
    """A sampler or pruner spec that names nothing known or has bad options."""


def _build(kind: str, table: dict[str, str], module: Any, spec: Mapping[str, Any] | None,
           default: str) -> Any:
    spec = dict(spec or {"name": default})
    name = str(spec.pop("name", default)).lower()
    if name not in table:
        raise AlgorithmSpecError(
            f"hydra.sweeper.{kind}.name: unknown {kind} {name!r}; expected one of {sorted(table)}"
        )
    cls = getattr(module, table[name])
    try:
        return cls(**spec)
    except TypeError as err:
        raise AlgorithmSpecError(f"hydra.sweeper.{kind} ({name}): {err}") from err


def make_pruner(spec: Mapping[str, Any] | None) -> optuna.pruners.BasePruner:
    """``{"name": "median"|"hyperband"|"none"|..., **kwargs}`` -> an Optuna pruner."""
    return _build("pruner", PRUNERS, optuna.pruners, spec, "none")


def trial_seed(seed: int, number: int) -> int:
    """The seed of trial ``number``'s random stream in a study sampled with ``seed``."""
    digest = hashlib.blake2b(f"aslexp-sampler:{int(seed)}:{int(number)}".encode(), digest_size=4)
    return int.from_bytes(digest.digest(), "big")


class PerTrialSeedSampler(BaseSampler):
    """A seeded sampler whose random stream is chosen per trial, from (seed, trial number).

    Workers that start together (by hand, as tasks of one Slurm array, or resumed at once) all
    load the same study with the same seed; with one stream per process they would replay the
    same points. Here each trial's random draws come from ``trial_seed(seed, number)``, and the
    storage hands out each trial number once: workers never duplicate a point, and a sweep is
    still reproducible (trial N draws the same numbers whichever worker runs it; model-based
    samplers such as TPE also depend on which trials had finished when N was asked for).
    """

    def __init__(self, spec: Mapping[str, Any], seed: int) -> None:
        self._spec = {k: v for k, v in spec.items() if k != "seed"}
        self._seed = int(seed)
        self._sampler = self._for_trial(0)

    def _for_trial(self, number: int) -> BaseSampler:
        return _build("sampler", SAMPLERS, optuna.samplers,
                      {**self._spec, "seed": trial_seed(self._seed, number)}, "tpe")

    def before_trial(self, study: optuna.Study, trial: FrozenTrial) -> None:
        self._sampler = self._for_trial(trial.number)
        self._sampler.before_trial(study, trial)

    def infer_relative_search_space(self, study: optuna.Study,
                                    trial: FrozenTrial) -> dict[str, BaseDistribution]:
        return self._sampler.infer_relative_search_space(study, trial)

    def sample_relative(self, study: optuna.Study, trial: FrozenTrial,
                        search_space: dict[str, BaseDistribution]) -> dict[str, Any]:
        return self._sampler.sample_relative(study, trial, search_space)

    def sample_independent(self, study: optuna.Study, trial: FrozenTrial, param_name: str,
                           param_distribution: BaseDistribution) -> Any:
        return self._sampler.sample_independent(study, trial, param_name, param_distribution)

    def after_trial(self, study: optuna.Study, trial: FrozenTrial, state: TrialState,
                    values: Sequence[float] | None) -> None:
        self._sampler.after_trial(study, trial, state, values)

    def reseed_rng(self) -> None:
        self._sampler.reseed_rng()


# Samplers whose seed is not a random stream but part of the design: QMC's seed scrambles one
# low-discrepancy sequence that the study walks along (its position is kept in the storage).
_SEED_IS_DESIGN = {"qmc"}


ATTR_SAMPLER = "aslexp_sampler"  # study and trial user attr: the sampler's settings (sampler_settings)


def _plain_setting(value: Any) -> Any:
    """A setting as JSON: numbers, text, lists and maps as they are; a function by its name; an
    object (a sampler given as another's fallback, a mutation) by its class."""
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    if isinstance(value, Mapping):
        return {str(k): _plain_setting(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain_setting(v) for v in value]
    if callable(value) and hasattr(value, "__qualname__"):
        return f"{getattr(value, '__module__', '')}.{value.__qualname__}"
    return type(value).__name__


def sampler_settings(spec: Mapping[str, Any] | None, study: optuna.Study | None = None) -> dict[str, Any]:
    """Every setting of the sampler ``spec`` builds, the Optuna version's own defaults included
    (Optuna 5's TPE is multivariate unless told otherwise, decided per ``study``: a 4.x study's
    seed then draws other points). ``{"name", "class", "optuna", "seed", "seed_per_trial",
    "settings": {...}}``: what a study and its trials record, so that a resumed or repeated sweep
    can tell it samples differently."""
    spec = dict(spec or {"name": "tpe"})
    name = str(spec.get("name", "tpe")).lower()
    built = _build("sampler", SAMPLERS, optuna.samplers, spec, "tpe")
    # TPE keeps some settings in a tuple of its own (its "multivariate" there is unused: skipped)
    estimator = getattr(built, "_parzen_estimator_parameters", None)
    settings = {}
    for key, parameter in inspect.signature(type(built).__init__).parameters.items():
        if key == "self" or parameter.kind in (parameter.VAR_POSITIONAL, parameter.VAR_KEYWORD):
            continue
        value = spec.get(key, None if parameter.default is parameter.empty else parameter.default)
        if hasattr(built, f"_{key}"):
            value = getattr(built, f"_{key}")
        elif key in getattr(estimator, "_fields", ()) and key != "multivariate":
            value = getattr(estimator, key)
        settings[key] = _plain_setting(value)
    if study is not None and hasattr(built, "_is_multivariate"):  # None: Optuna decides by the study
        settings["multivariate"] = bool(built._is_multivariate(study))
    seed = spec.get("seed")
    if "seed" in settings:
        settings["seed"] = seed  # the study's seed (each trial's own stream is derived from it)
    return {"name": name, "class": type(built).__name__, "optuna": optuna.__version__,
            "seed": seed, "seed_per_trial": seed is not None and name not in _SEED_IS_DESIGN,
            "settings": settings}


def sampler_changes(before: Mapping[str, Any], now: Mapping[str, Any]) -> list[str]:
    """``key: old -> new`` for each setting (or the class, the Optuna version) that differs."""
    changes = [f"{key}: {before.get(key)!r} -> {now.get(key)!r}" for key in ("class", "optuna", "seed")
               if before.get(key) != now.get(key)]  # fmt: skip
    old, new = before.get("settings") or {}, now.get("settings") or {}
    changes += [f"{key}: {old.get(key)!r} -> {new.get(key)!r}" for key in sorted(set(old) | set(new))
                if old.get(key) != new.get(key)]  # fmt: skip
    return changes


def record_sampler_settings(study: optuna.Study, settings: Mapping[str, Any]) -> list[str]:
    """Keep ``settings`` in the study (``ATTR_SAMPLER``; each trial also records the settings that
    drew it). A study sampled before with other settings (another Optuna, another default) keeps
    going, with one warning saying what changed; returns those changes."""
    before = study.user_attrs.get(ATTR_SAMPLER)
    changes = sampler_changes(before, settings) if isinstance(before, Mapping) else []
    if changes:
        log.warning("study %r was sampled with other settings before (%s): trials from now on are drawn "
                    "with these, and its seed does not repeat the earlier sequence", study.study_name,
                    "; ".join(changes))  # fmt: skip
    if before != settings:
        study.set_user_attr(ATTR_SAMPLER, dict(settings))
    return changes


def make_sampler(spec: Mapping[str, Any] | None) -> optuna.samplers.BaseSampler:
    """``{"name": "tpe"|"random"|..., "seed": S, **kwargs}`` -> an Optuna sampler.

    With a seed, each trial draws from its own stream (:class:`PerTrialSeedSampler`), so that
    workers started together never replay each other's points. Without one, every process
    draws from fresh OS entropy.
    """
    spec = dict(spec or {"name": "tpe"})
    name = str(spec.get("name", "tpe")).lower()
    sampler = _build("sampler", SAMPLERS, optuna.samplers, spec, "tpe")  # validates the spec
    if spec.get("seed") is None or name in _SEED_IS_DESIGN:
        return sampler
    return PerTrialSeedSampler(spec, int(spec["seed"]))
