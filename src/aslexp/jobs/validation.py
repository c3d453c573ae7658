"""A job's configuration checked at the edge, before anything runs (the keys: :mod:`aslexp.config_schema`).

* A single run is checked by :class:`ConfigCheck`, a Hydra callback that every job config lists
  (``conf/hydra/callbacks/aslexp.yaml``), in ``on_run_start``: before Hydra writes ``.hydra/`` or
  opens the job's log, so a refused run leaves no folder at all. The imitate job's experiment is
  also assembled there (:func:`check_imitation_setup`: a motion of another body's width,
  a bad group value). One line on stderr names the key,
  the value given and what is expected (``aslexp imitate: ppo.total_steps=abc: expected an integer
  >= 0``); exit 2.
* A multirun is checked once in ``on_multirun_start``, for the values every job shares (exit 2,
  nothing written), and each job again by :func:`check_config` at the start of its body, for the
  swept values: a job with a bad one is recorded as failed in its run.json with that line and,
  as any failed job of a multirun, the sweep goes on (``fail_fast=true``: it stops, exit 2).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from hydra.core.hydra_config import HydraConfig
from hydra.experimental.callback import Callback
from omegaconf import DictConfig, ListConfig, OmegaConf

from aslexp.config_schema import check_job
from aslexp.errors import ConfigError

_ABSENT = object()
# Jobs composed on conf/imitate.yaml (their configs include it): checked as the imitate job is.
IMITATION_JOBS = ("imitate", "evaluate", "plan")


def _selector(cfg: DictConfig):
    def select(path: str) -> Any:
        value = OmegaConf.select(cfg, path, default=_ABSENT)
        if value is _ABSENT:
            raise KeyError(path)
        if isinstance(value, (DictConfig, ListConfig)):
            return OmegaConf.to_container(value, resolve=True)
        return value

    return select


def check_config(job: str, cfg: DictConfig) -> None:
    """Raise :class:`~aslexp.errors.ConfigError` (exit 2) if a key of ``job`` has a value of the
    wrong type or out of range."""
    check_job("imitate" if job in IMITATION_JOBS else job, _selector(cfg))


def name_motion_after_its_file(cfg: DictConfig, overrides: list[str]) -> None:
    """A motion given by file (``motion.file=PATH``) without ``motion.name`` is named after the
    file (its stem), not after the default motion whose file it replaced: logs, metrics.json and
    the run folder's name say ``walk``, not ``A``."""
    keys = {o.split("=", 1)[0].lstrip("+~") for o in overrides}
    if "motion.file" not in keys or "motion.name" in keys:
        return
    file = OmegaConf.select(cfg, "motion.file", default=None)
    if file:
        from omegaconf import open_dict, read_write

        with read_write(cfg), open_dict(cfg):
            cfg.motion.name = Path(str(file)).stem


def check_imitation_setup(cfg: DictConfig) -> None:
    """Assemble the imitate job's experiment without simulating (raises what the run would raise at
    its start: a motion of another body's width, a bad group value)."""
    from aslexp.data.root import resolve_data_root
    from aslexp.envs.assembly import ImitationSetup

    groups = ("motion", "body", "controller", "reward", "env", "engine")
    plain = {key: OmegaConf.to_container(cfg[key], resolve=True) for key in groups if key in cfg}
    if OmegaConf.select(cfg, "policy", default=None):  # a performance: the policy's run's groups, this motion
        from aslexp.jobs.performing import performing_config

        performing, _ = performing_config({**plain, "policy": cfg.policy})
        plain = {**{key: performing[key] for key in groups if key in performing}, "motion": plain["motion"]}
    ImitationSetup.from_config(plain, resolve_data_root(OmegaConf.select(cfg, "data_root", default=None)))


class ConfigCheck(Callback):
    """Refuse bad values before Hydra writes anything (see the module docstring)."""

    def _check(self, config: DictConfig) -> None:
        from aslexp.jobs._common import JobAbort

        job = OmegaConf.select(config, "hydra.job.config_name", default=None)
        if not job:
            return
        HydraConfig.instance().set_config(config)  # ${hydra:...} in a value needs it
        try:
            check_config(str(job), config)
        except ConfigError as err:
            # A BaseException: Hydra turns an Exception raised in a callback into a warning.
            raise JobAbort(str(err), code=2) from None

    def _check_setup(self, config: DictConfig) -> None:
        """The imitate job's experiment parsed once here (motion, body, every group; no simulation,
        ~10 ms): a motion of the wrong width or a bad group value is refused before the run folder."""
        from aslexp.jobs._common import JobAbort, one_line

        if OmegaConf.select(config, "hydra.job.config_name", default=None) not in IMITATION_JOBS:
            return
        try:
            check_imitation_setup(config)
        except (ValueError, OSError, KeyError, TypeError) as err:
            raise JobAbort(one_line(err), code=2) from None

    def on_run_start(self, config: DictConfig, **kwargs: Any) -> None:
        self._check(config)
        if OmegaConf.select(config, "motion", default=None) is not None:
            name_motion_after_its_file(config, list(config.hydra.overrides.task))
        self._check_setup(config)

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        self._check(config)
