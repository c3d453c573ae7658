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
* A value that is part of the run folder's name (``${classifier.name}`` in ``hydra.run.dir``) is
  a name: a ``/`` in it (``classifier.name=../../x``) would put the folder elsewhere, outside
  ``outputs/`` even, so it is refused before Hydra creates the folder (:func:`check_folder_names`;
  in a multirun every swept value too, as Hydra creates a job's folder before any job code runs).
* A job with a classifier refuses an unknown classifier name before its folder, listing the
  known ones (:func:`aslexp.recognition.registry.check_classifier_name`).
"""

from __future__ import annotations

import logging
from contextlib import contextmanager
import re
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
# Jobs whose config has a classifier group (classifier.name, classifier.module).
CLASSIFIER_JOBS = ("recognize", "retrieve", "glosses")
# A key interpolated in a folder template: ${motion.name}, not a resolver (${now:...}) nor Hydra's own.
_INTERPOLATED_KEY = re.compile(r"\$\{([A-Za-z_][\w.]*)\}")
_SEPARATORS = ("/", "\\")


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
    if job in CLASSIFIER_JOBS and OmegaConf.select(cfg, "classifier.name", default=None) is not None:
        from aslexp.recognition.registry import check_classifier_name

        check_classifier_name(str(cfg.classifier.name), OmegaConf.select(cfg, "classifier.module", default=None))


def _template(config: DictConfig, path: str) -> str:
    """``hydra.run.dir`` (or another folder key) as written, before interpolation."""
    node, _, leaf = path.rpartition(".")
    raw = OmegaConf.to_container(OmegaConf.select(config, node), resolve=False)
    return str(raw.get(leaf) or "") if isinstance(raw, dict) else ""


def swept_values(config: DictConfig) -> dict[str, list[str]]:
    """Per key, the values a multirun sweeps it over (command line and ``hydra.sweeper.params``);
    a range the sweeper samples (``interval(...)``) has no list and is left out."""
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.errors import HydraException

    params = OmegaConf.select(config, "hydra.sweeper.params", default=None) or {}
    lines = [str(o) for o in OmegaConf.select(config, "hydra.overrides.task", default=None) or ()]
    lines += [f"{k}={v}" for k, v in params.items()]
    swept: dict[str, list[str]] = {}
    for override in OverridesParser.create().parse_overrides(lines):
        if not override.is_sweep_override():
            continue
        try:
            values = list(override.sweep_iterator())
        except HydraException:  # an interval: sampled, not listed
            continue
        # a quoted value ('00433') as its text
        swept.setdefault(override.get_key_element(), []).extend(str(getattr(v, "text", v)) for v in values)
    return swept


def check_folder_names(config: DictConfig, folder_keys: tuple[str, ...],
                       swept: dict[str, list[str]] | None = None) -> None:
    """Refuse a value (or a swept value) interpolated in the run folder's name that holds a path
    separator: the folder would land elsewhere (``classifier.name=../../x``: outside ``outputs/``)."""
    for folder_key in folder_keys:
        template = _template(config, folder_key)
        for name in dict.fromkeys(_INTERPOLATED_KEY.findall(template)):
            if name.startswith("hydra."):
                continue
            given = OmegaConf.select(config, name, default=None)
            for value in [given, *(swept or {}).get(name, [])]:
                if value is not None and any(sep in str(value) for sep in _SEPARATORS):
                    raise ConfigError(f"{name}={value}: expected a name without '/' or '\\' (it is part of "
                                      f"the run folder's name, {folder_key})")


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
    with _warnings_left_to_the_job():
        ImitationSetup.from_config(plain, resolve_data_root(OmegaConf.select(cfg, "data_root", default=None)))


@contextmanager
def _warnings_left_to_the_job():
    """The motion loader's warnings (a frame duration out of range) silenced while the edge check
    loads the motion: the job loads it again and says them once, in its run folder's log too."""
    motion_log = logging.getLogger("aslexp.motion")
    level = motion_log.level
    motion_log.setLevel(logging.ERROR)
    try:
        yield
    finally:
        motion_log.setLevel(level)


def check_controller_and_env(cfg: DictConfig) -> None:
    """The controller and env groups read as a job reads them (gains, rates), without a body."""
    from aslexp.envs.spec import EnvSpec
    from aslexp.sim.pd import ControllerSpec

    ControllerSpec.parse(OmegaConf.to_container(cfg.controller, resolve=True))
    EnvSpec.parse(OmegaConf.to_container(cfg.env, resolve=True))


class ConfigCheck(Callback):
    """Refuse bad values before Hydra writes anything (see the module docstring)."""

    def _check(self, config: DictConfig, multirun: bool = False) -> None:
        from aslexp.jobs._common import JobAbort

        job = OmegaConf.select(config, "hydra.job.config_name", default=None)
        if not job:
            return
        HydraConfig.instance().set_config(config)  # ${hydra:...} in a value needs it
        try:
            if multirun:
                check_folder_names(config, ("hydra.sweep.dir", "hydra.sweep.subdir"), swept_values(config))
            else:
                check_folder_names(config, ("hydra.run.dir",))
            check_config(str(job), config)
        except ConfigError as err:
            # A BaseException: Hydra turns an Exception raised in a callback into a warning.
            raise JobAbort(str(err), code=2) from None

    def _check_setup(self, config: DictConfig) -> None:
        """The imitate job's experiment parsed once here (motion, body, every group; no simulation,
        ~10 ms): a motion of the wrong width or a bad group value is refused before the run folder.
        tune_pd's controller and env are read the same way (a negative gain, a rate out of range)."""
        from aslexp.jobs._common import JobAbort, one_line

        job = OmegaConf.select(config, "hydra.job.config_name", default=None)
        if job not in IMITATION_JOBS and job != "tune_pd":
            return
        try:
            if job == "tune_pd":
                check_controller_and_env(config)
            else:
                check_imitation_setup(config)
        except (ValueError, OSError, KeyError, TypeError) as err:
            raise JobAbort(one_line(err), code=2) from None

    def on_run_start(self, config: DictConfig, **kwargs: Any) -> None:
        self._check(config)
        if OmegaConf.select(config, "motion", default=None) is not None:
            name_motion_after_its_file(config, list(config.hydra.overrides.task))
        self._check_setup(config)

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        self._check(config, multirun=True)
