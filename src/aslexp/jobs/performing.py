"""``aslexp imitate policy=RUN_DIR``: a trained policy performs another motion (issue 38 item 2)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from aslexp.errors import ConfigError


def performing_config(cfg: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any]]:
    """``policy=RUN_DIR``: the config a trained policy performs this run's motion under, and what the
    run folder records of the policy. Every group but the motion is the policy's run's (the body,
    controller, reward, observation and action it was trained with, and its evaluation protocol);
    the motion, seed, render and plots are this run's. Nothing is trained (issue 38 item 2)."""
    from aslexp.reports.report import run_config

    run_dir = Path(str(cfg["policy"]))
    checkpoint = run_dir / "checkpoints" / "last.pt" if run_dir.is_dir() else run_dir
    if run_dir.is_file():
        run_dir = checkpoint.parent.parent
    if not checkpoint.is_file():
        raise ConfigError(f"policy={cfg['policy']}: no checkpoint {checkpoint} (expected a run folder of "
                          f"`aslexp imitate` with checkpoints/last.pt, or a checkpoint file)")
    try:
        theirs = run_config(run_dir)
    except FileNotFoundError as err:
        raise ConfigError(f"policy={cfg['policy']}: {err}") from None
    own = {key: cfg.get(key) for key in ("motion", "seed", "render", "plots", "data_root")}
    performing = {**theirs, **own, "policy": None, "resume": None, "train_motions": None, "planner": None,
                  "report": {}}
    # what the policy trained on: its pool (the motion it held out) or its run's motion
    from aslexp.reports.job_table import read_json

    pool = (read_json(run_dir / "metrics.json") or {}).get("train_motions") if (run_dir / "metrics.json").is_file() else None
    record = {"run": str(run_dir), "checkpoint": str(checkpoint),
              "trained_on": pool or (theirs.get("motion") or {}).get("name"),
              "train_motions": (theirs.get("train_motions") or {}).get("name")}
    return performing, record
