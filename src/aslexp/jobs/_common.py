"""Shared plumbing for the Hydra entry points (the only place, with cli.py, that knows Hydra)."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf

from aslexp.runs.record import Run, start_run
from aslexp.seeding import seed_everything  # noqa: F401  (re-exported for the jobs)

PROJECT_ROOT = Path(__file__).resolve().parents[3]
CONF_DIR = str(PROJECT_ROOT / "conf")

log = logging.getLogger("aslexp")


def run_dir() -> Path:
    """This job's output directory (Hydra's runtime.output_dir)."""
    return Path(HydraConfig.get().runtime.output_dir)


def to_dict(cfg: DictConfig | Any) -> Any:
    """Plain Python containers for the layers below Hydra."""
    if isinstance(cfg, DictConfig):
        return OmegaConf.to_container(cfg, resolve=True)
    return cfg


def begin(job: str, cfg: DictConfig) -> Run:
    """Start the run record in the Hydra output dir (refuses to overwrite a finished run)."""
    import shlex
    import sys

    overrides = list(HydraConfig.get().overrides.task)
    extra = {
        # The command that re-runs exactly this job (in a multirun: this one job, not the sweep).
        "command": shlex.join(["aslexp", job, *overrides]),
        "argv": list(sys.argv),
        "overrides": overrides,
    }
    seed = cfg.get("seed")
    return start_run(run_dir(), job, seed=seed, overwrite=bool(cfg.get("overwrite", False)), extra=extra)


def in_multirun() -> bool:
    from hydra.types import RunMode

    return HydraConfig.get().mode == RunMode.MULTIRUN


def run_guarded(job: str, cfg: DictConfig, body) -> float:
    """Run ``body(run) -> float`` inside a run record and return its objective.

    In a multirun, unless ``fail_fast``, an exception is logged and recorded in run.json as a
    failed run and the job returns NaN, so that one bad trial never ends the whole sweep (Optuna
    records a NaN trial as failed). Pruning (optuna.TrialPruned) and Ctrl-C always propagate.
    """
    import optuna

    run = begin(job, cfg)
    try:
        value = float(body(run))
    except (optuna.TrialPruned, KeyboardInterrupt) as exc:
        run.finish("pruned" if isinstance(exc, optuna.TrialPruned) else "interrupted", repr(exc))
        raise
    except Exception as exc:  # noqa: BLE001 - recorded, then re-raised or turned into NaN
        run.finish("failed", f"{type(exc).__name__}: {exc}")
        if cfg.get("fail_fast", False) or not in_multirun():
            raise
        log.exception("%s failed; recorded in %s/run.json, the sweep goes on", job, run.dir)
        return float("nan")
    run.finish("completed")
    return value
