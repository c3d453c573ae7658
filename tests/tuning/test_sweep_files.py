"""Every file in sweeps/ composes with its job's config, and its search space parses into Optuna
distributions whose parameters exist in the composed config (a typo in a key fails here, not after
hours of trials)."""

from __future__ import annotations

from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from aslexp.jobs._common import CONF_DIR
from hydra_plugins.aslexp_optuna_sweeper._space import parse_search_space

SWEEPS = sorted(p.stem for p in (Path(CONF_DIR).parent / "sweeps").glob("*.yaml"))
JOB = {"classifier": "recognize", "pd_gains": "tune_pd", "ppo": "imitate", "kfactors": "imitate",
       "quadratic": "quadratic", "mpc": "imitate", "retargeting": "retarget"}


def _job(sweep: str) -> str:
    return next(job for prefix, job in JOB.items() if sweep.startswith(prefix))


@pytest.mark.parametrize("sweep", SWEEPS)
def test_sweep_composes_and_its_space_names_real_keys(sweep):
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        cfg = compose(config_name=_job(sweep), overrides=[f"+sweeps={sweep}"], return_hydra_config=True)
    params = OmegaConf.to_container(cfg.hydra.sweeper.params, resolve=False)
    assert params, f"{sweep}: no search space"
    space = parse_search_space(params, [])
    job_cfg = OmegaConf.masked_copy(cfg, [k for k in cfg if k != "hydra"])
    for key in space.distributions:
        assert OmegaConf.select(job_cfg, key.lstrip("+"), default="<missing>") != "<missing>", \
            f"sweeps/{sweep}.yaml searches {key!r}, which the composed {_job(sweep)} config does not have"
