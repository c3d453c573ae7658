"""Metric loggers selected by the `logger` config group: none | csv | tensorboard | wandb.

All take ``log(metrics, step)`` and ``close()``; the run directory is the single place they write.
wandb runs offline unless an API key is configured, so nothing leaves the machine by default.
"""

from __future__ import annotations

import csv
import logging
import os
from pathlib import Path
from typing import Any, Protocol

from aslexp.files import atomic_path

log = logging.getLogger(__name__)


class MetricLogger(Protocol):
    def log(self, metrics: dict[str, float], step: int) -> None: ...

    def close(self) -> None: ...


class NoLogger:
    def log(self, metrics: dict[str, float], step: int) -> None:
        return None

    def close(self) -> None:
        return None


class CsvLogger:
    """Appends one row per call to ``history.csv``; new keys extend the header."""

    def __init__(self, run_dir: Path, filename: str = "history.csv"):
        self.path = Path(run_dir) / filename
        self.rows: list[dict[str, Any]] = []

    def log(self, metrics: dict[str, float], step: int) -> None:
        self.rows.append({"step": step, **metrics})
        fields: list[str] = []
        for row in self.rows:
            fields += [k for k in row if k not in fields]
        with atomic_path(self.path, make_parents=False) as tmp, open(tmp, "w", newline="", encoding="utf-8") as fh:
            writer = csv.DictWriter(fh, fieldnames=fields)
            writer.writeheader()
            writer.writerows(self.rows)

    def close(self) -> None:
        return None


class TensorBoardLogger:
    def __init__(self, run_dir: Path):
        try:
            from torch.utils.tensorboard import SummaryWriter
        except ImportError as err:  # tensorboard is an optional extra
            raise ImportError(
                "logger=tensorboard needs the tensorboard package: pip install 'aslexp[tensorboard]'"
            ) from err
        self.writer = SummaryWriter(log_dir=str(Path(run_dir) / "tensorboard"))

    def log(self, metrics: dict[str, float], step: int) -> None:
        for key, value in metrics.items():
            self.writer.add_scalar(key, value, step)

    def close(self) -> None:
        self.writer.close()


class WandbLogger:
    def __init__(self, run_dir: Path, project: str, config: dict[str, Any], mode: str | None):
        try:
            import wandb
        except ImportError as err:  # wandb is an optional extra
            raise ImportError("logger=wandb needs wandb: pip install 'aslexp[wandb]'") from err
        if mode is None:
            has_key = bool(os.environ.get("WANDB_API_KEY")) or (Path.home() / ".netrc").exists()
            mode = "online" if has_key else "offline"
        self.run = wandb.init(project=project, dir=str(run_dir), config=config, mode=mode)
        log.info("wandb logging %s (project %s)", mode, project)

    def log(self, metrics: dict[str, float], step: int) -> None:
        self.run.log(metrics, step=step)

    def close(self) -> None:
        self.run.finish()


def make_logger(cfg: dict[str, Any], run_dir: Path, run_config: dict[str, Any]) -> MetricLogger:
    name = cfg.get("name", "none")
    if name == "none":
        return NoLogger()
    if name == "csv":
        return CsvLogger(run_dir)
    if name == "tensorboard":
        return TensorBoardLogger(run_dir)
    if name == "wandb":
        return WandbLogger(run_dir, cfg.get("project", "aslexp"), run_config, cfg.get("mode"))
    raise ValueError(f"logger.name={name!r}: expected one of none, csv, tensorboard, wandb")
