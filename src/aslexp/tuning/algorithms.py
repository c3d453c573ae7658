"""Samplers and pruners from plain specs: ``{"name": "median", "n_startup_trials": 5, ...}``.

The specs come from conf/hydra/sweeper/{sampler,pruner}/*.yaml; every other key is passed to the
Optuna class as a keyword argument, so any option Optuna documents can be set from config.
A job process rebuilds the study's pruner from the same spec (see :mod:`aslexp.tuning.context`).
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping, Sequence
from typing import Any

import optuna
from optuna.distributions import BaseDistribution
from optuna.samplers import BaseSampler
from optuna.trial import FrozenTrial, TrialState

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
