"""``aslexp evaluate policy=RUN_DIR`` (or ``aslexp imitate policy=RUN_DIR``): the config under which a
trained policy performs another motion."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from aslexp.errors import ConfigError


def run_policy_checkpoint(run_dir: Path) -> Path:
    """The policy a run folder ends with: the checkpoint its validation chose (selected.pt), else its last."""
    selected = run_dir / "checkpoints" / "selected.pt"
    return selected if selected.is_file() else run_dir / "checkpoints" / "last.pt"


def performing_config(cfg: dict[str, Any], keep: tuple[str, ...] = ()) -> tuple[dict[str, Any], dict[str, Any]]:
    """``policy=RUN_DIR``: the config a trained policy performs this run's motion under, and what the
    run folder records of the policy. Every group but the motion is the policy's run's (the body,
    controller, reward, observation and action it was trained with, its engine and its evaluation
    protocol); the motion, seed, render and plots are this run's, and so are the groups of ``keep``
    (``("engine",)``: the command named one). Nothing is trained."""
    from aslexp.reports.report import run_config

    run_dir = Path(str(cfg["policy"]))
    checkpoint = run_policy_checkpoint(run_dir) if run_dir.is_dir() else run_dir
    if run_dir.is_file():
        run_dir = checkpoint.parent.parent
    if not checkpoint.is_file():
        raise ConfigError(f"policy={cfg['policy']}: no checkpoint {checkpoint} (expected a run folder of "
                          f"`aslexp imitate` with checkpoints/last.pt, or a checkpoint file)")
    try:
        theirs = run_config(run_dir)
    except FileNotFoundError as err:
        raise ConfigError(f"policy={cfg['policy']}: {err}") from None
    own = {key: cfg.get(key) for key in ("motion", "seed", "render", "plots", "data_root", *keep)}
    performing = {**theirs, **own, "policy": None, "resume": None, "train_motions": None, "planner": None,
                  "report": {}}
    chosen_by = "this command" if "engine" in keep else "the policy's run"
    if not theirs.get("engine"):  # a run from before engines were a group: this command's (the default)
        performing["engine"], chosen_by = cfg.get("engine"), "this command (the policy's run records none)"
    # what the policy trained on: its pool (the motion it held out) or its run's motion
    from aslexp.runs.completed import read_json

    pool = (read_json(run_dir / "metrics.json") or {}).get("train_motions") if (run_dir / "metrics.json").is_file() else None
    record = {"run": str(run_dir), "checkpoint": str(checkpoint),
              "trained_on": pool or (theirs.get("motion") or {}).get("name"),
              "train_motions": (theirs.get("train_motions") or {}).get("name"),
              "engine": (performing.get("engine") or {}).get("name"),
              "trained_on_engine": (theirs.get("engine") or {}).get("name"),
              "engine_chosen_by": chosen_by}
    return performing, record
