"""Samplers and pruners from plain specs: ``{"name": "median", "n_startup_trials": 5, ...}``.

The specs come from conf/hydra/sweeper/{sampler,pruner}/*.yaml; every other key is passed to the
Optuna class as a keyword argument, so any option Optuna documents can be set from config.
A job process rebuilds the study's pruner from the same spec (see :mod:`aslexp.tuning.context`).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import optuna

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


def make_sampler(spec: Mapping[str, Any] | None, seed_offset: int = 0) -> optuna.samplers.BaseSampler:
    """``{"name": "tpe"|"random"|..., "seed": S, **kwargs}`` -> an Optuna sampler.

    ``seed_offset`` shifts a given seed, so that parallel workers and resumed sweeps do not
    replay the random start-up points of earlier processes (same seed, same first points).
    """
    spec = dict(spec or {"name": "tpe"})
    if spec.get("seed") is not None:
        spec["seed"] = int(spec["seed"]) + int(seed_offset)
    return _build("sampler", SAMPLERS, optuna.samplers, spec, "tpe")
