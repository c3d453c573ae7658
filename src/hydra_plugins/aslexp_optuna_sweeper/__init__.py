"""aslexp's Optuna sweeper: a Hydra Sweeper with persistent studies, resume, pruning and
asynchronous workers.

Selected by ``hydra/sweeper=optuna`` through the project's conf/hydra/sweeper/optuna.yaml. Each
worker loops ask -> launch one job through the configured Hydra launcher -> tell, so the basic
launcher, submitit_local and Slurm all work unchanged; see :mod:`aslexp.tuning.worker` for the
guarantees and docs/sweeps.md for recipes.

This module stays light (Hydra imports every plugin module at every start, sweep or not): the
implementation, which imports Optuna, is loaded on first use from ``_impl``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from hydra.core.config_search_path import ConfigSearchPath
from hydra.core.config_store import ConfigStore
from hydra.plugins.search_path_plugin import SearchPathPlugin
from hydra.plugins.sweeper import Sweeper
from hydra.types import HydraContext, TaskFunction
from omegaconf import DictConfig

from aslexp.paths import CONF_DIR

_STOCK_PROVIDER = "optuna_sweeper"  # hydra-optuna-sweeper's ConfigStore provider name


class AslexpOptunaSweeper(Sweeper):
    """Thin Hydra entry point; the work is done by ``_impl.SweeperImpl``."""

    def __init__(self, **config: Any) -> None:
        from hydra_plugins.aslexp_optuna_sweeper._impl import SweeperImpl

        self.impl = SweeperImpl(**config)

    def setup(self, *, hydra_context: HydraContext, task_function: TaskFunction,
              config: DictConfig) -> None:
        self.impl.setup(hydra_context=hydra_context, task_function=task_function, config=config)

    def sweep(self, arguments: list[str]) -> Any:
        return self.impl.sweep(arguments)


class AslexpOptunaConfigs(SearchPathPlugin):
    """Makes ``hydra/sweeper=optuna`` mean this sweeper even where hydra-optuna-sweeper is installed.

    The stock plugin stores structured configs named ``hydra/sweeper/optuna`` and
    ``hydra/sweeper/sampler/{tpe,random,...}`` in Hydra's ConfigStore. Hydra 1.3 validates a YAML
    file against a ConfigStore entry of the same name ("automatic schema matching") and refuses
    one whose schema has a defaults list, so our conf/hydra/sweeper/*.yaml could not load while
    those entries exist. Hydra calls this hook after importing all plugins and before composing,
    so dropping the stock entries here is reliable; the stock Sweeper class itself is untouched.
    """

    def manipulate_search_path(self, search_path: ConfigSearchPath) -> None:
        if (CONF_DIR / "hydra" / "sweeper" / "optuna.yaml").exists():
            _drop_stock_optuna_entries(ConfigStore.instance().repo)


def _drop_stock_optuna_entries(repo: dict) -> None:
    sweeper_group = repo.get("hydra", {}).get("sweeper", {})
    groups = [sweeper_group, sweeper_group.get("sampler", {})]
    for group in groups:
        for name in [n for n, node in group.items()
                     if getattr(node, "provider", None) == _STOCK_PROVIDER]:
            del group[name]
