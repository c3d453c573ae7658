"""The jobs of an imitate multirun trained as one program (``hydra/launcher=stacked``;
:mod:`aslexp.jobs.stacked` says what it does and refuses).

Hydra's basic launcher runs the jobs one after another; this one composes all of them first, trains
them together into their own folders, then runs each job in this process with ``resume=`` its folder,
which evaluates the trained policy and writes the folder as any imitate run's (the job's overrides
and command in run.json include that ``resume=``).
"""

from __future__ import annotations

import copy
import logging
import os
from collections.abc import Sequence
from pathlib import Path

from hydra.core.hydra_config import HydraConfig
from hydra.core.utils import JobReturn, configure_log, filter_overrides, run_job, setup_globals
from hydra.plugins.launcher import Launcher
from omegaconf import DictConfig, OmegaConf, open_dict, read_write

log = logging.getLogger(__name__)


class StackedLauncher(Launcher):
    def __init__(self) -> None:
        super().__init__()
        self.config = self.hydra_context = self.task_function = None

    def setup(self, *, hydra_context, task_function, config: DictConfig) -> None:
        self.config, self.hydra_context, self.task_function = config, hydra_context, task_function

    def _job(self, overrides: Sequence[str], idx: int) -> tuple[DictConfig, Path]:
        """The job's sweep config and its folder, as Hydra's run_job resolves them."""
        sweep_config = self.hydra_context.config_loader.load_sweep_config(self.config, list(overrides))
        with open_dict(sweep_config):
            sweep_config.hydra.job.id = sweep_config.hydra.job.num = idx
        HydraConfig.instance().set_config(sweep_config)
        folder = Path(str(OmegaConf.select(sweep_config, "hydra.sweep.dir"))) / str(
            OmegaConf.select(sweep_config, "hydra.sweep.subdir"))
        return sweep_config, folder

    def launch(self, job_overrides: Sequence[Sequence[str]], initial_job_idx: int) -> Sequence[JobReturn]:
        from aslexp.jobs.stacked import task_config, train_together

        setup_globals()
        configure_log(self.config.hydra.hydra_logging, self.config.hydra.verbose)
        Path(str(self.config.hydra.sweep.dir)).mkdir(parents=True, exist_ok=True)
        jobs = [self._job(overrides, initial_job_idx + k) for k, overrides in enumerate(job_overrides)]
        log.info("Training %d jobs together", len(jobs))
        for k, overrides in enumerate(job_overrides):
            log.info("\t#%d : %s", initial_job_idx + k, " ".join(filter_overrides(overrides)))
        cfgs = []
        for (sweep_config, _), overrides in zip(jobs, job_overrides):
            HydraConfig.instance().set_config(sweep_config)
            task = copy.deepcopy(sweep_config)
            with read_write(task), open_dict(task):
                del task["hydra"]
            cfgs.append(task_config(task, list(overrides)))
        train_together(cfgs, [os.path.abspath(folder) for _, folder in jobs])
        returns = []
        for (_, folder), overrides, idx in zip(jobs, job_overrides, range(initial_job_idx, initial_job_idx + len(jobs))):
            finishing = [*overrides, f"resume={os.path.abspath(folder)}"]  # nothing left to train: evaluated
            sweep_config, same = self._job(finishing, idx)
            if same != folder:
                from aslexp.errors import ConfigError

                raise ConfigError(f"hydra/launcher=stacked: hydra.sweep.subdir names job {idx}'s folder {same} "
                                  f"once resume= is added, not {folder}: name it by the job (the default, "
                                  "${hydra.job.num})")
            returns.append(run_job(hydra_context=self.hydra_context, task_function=self.task_function,
                                   config=sweep_config, job_dir_key="hydra.sweep.dir",
                                   job_subdir_key="hydra.sweep.subdir"))
            configure_log(self.config.hydra.hydra_logging, self.config.hydra.verbose)
        return returns
