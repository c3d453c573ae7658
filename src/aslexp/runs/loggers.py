"""Metric loggers selected by the `logger` config group: none | csv | tensorboard | wandb.

Every logger takes ``log(metrics, step)`` for each epoch / rollout / evaluation and
``close(summary)`` once, with the job's final numbers; the run's configuration is logged as its
hyper-parameters. The run directory is the single place they write:

- ``csv``: ``history.csv``, one row per step, one column per metric (new keys extend the header).
- ``tensorboard``: ``tensorboard/`` event files through torchrl's ``TensorboardLogger``: every
  metric as a scalar, and at close the flattened configuration as TensorBoard hparams with the
  summary as their metrics (``hparam/<name>``), so the HParams tab compares runs.
- ``wandb``: offline (``wandb/offline-run-*``, ``wandb sync`` uploads it later) unless
  ``WANDB_MODE`` says otherwise, ``logger.mode`` is set, or a W&B key exists (``WANDB_API_KEY``,
  or a ``~/.netrc`` entry for the W&B host: an entry for another host does not count). If going
  online fails (no or bad credentials, no network) it warns and logs offline; it never ends the
  job. The summary holds the job's final numbers, not just the last step's.

Non-numeric and non-finite values are left out of scalar logs (NaN would break TensorBoard's
charts); the CSV keeps them as written.
"""

from __future__ import annotations

import csv
import logging
import math
import netrc
import os
from numbers import Real
from pathlib import Path
from typing import Any
from urllib.parse import urlparse

from aslexp.files import atomic_path

log = logging.getLogger(__name__)
LOGGERS = ("none", "csv", "tensorboard", "wandb")
WANDB_HOST = "https://api.wandb.ai"


def scalars(metrics: dict[str, Any]) -> dict[str, float]:
    """The finite real numbers of ``metrics`` (bools and strings are not metrics)."""
    return {k: float(v) for k, v in metrics.items()
            if isinstance(v, Real) and not isinstance(v, bool) and math.isfinite(float(v))}  # fmt: skip


def flatten(config: Any, prefix: str = "") -> dict[str, Any]:
    """A nested configuration as ``{"a/b/c": value}`` with values TensorBoard's hparams accept
    (int, float, str, bool; lists and None as text)."""
    if isinstance(config, dict):
        items: dict[str, Any] = {}
        for key, value in config.items():
            items.update(flatten(value, f"{prefix}{key}/"))
        return items
    key = prefix.rstrip("/")
    if isinstance(config, (bool, int, float, str)):
        return {key: config}
    return {key: str(config)}


class MetricLogger:
    """The interface, and the ``none`` logger."""

    def log(self, metrics: dict[str, Any], step: int) -> None:
        return None

    def close(self, summary: dict[str, Any] | None = None) -> None:
        return None


NoLogger = MetricLogger


class CsvLogger(MetricLogger):
    """Rewrites ``history.csv`` (atomically) with one row per call; new keys extend the header."""

    def __init__(self, run_dir: Path, filename: str = "history.csv"):
        self.path = Path(run_dir) / filename
        self.rows: list[dict[str, Any]] = []

    def log(self, metrics: dict[str, Any], step: int) -> None:
        self.rows.append({"step": step, **metrics})
        fields: list[str] = []
        for row in self.rows:
            fields += [k for k in row if k not in fields]
        with atomic_path(self.path, make_parents=False) as tmp, open(tmp, "w", newline="", encoding="utf-8") as fh:
            writer = csv.DictWriter(fh, fieldnames=fields)
            writer.writeheader()
            writer.writerows(self.rows)


class TensorBoardLogger(MetricLogger):
    """torchrl's TensorboardLogger for the scalars; hparams with the summary at close."""

    def __init__(self, run_dir: Path, hparams: dict[str, Any]):
        try:
            from torchrl.record.loggers import TensorboardLogger
        except ImportError as err:  # tensorboard is a dependency; only a broken install gets here
            raise ImportError("logger=tensorboard needs tensorboard: pip install tensorboard") from err
        self.logger = TensorboardLogger(exp_name="tensorboard", log_dir=str(run_dir))
        self.hparams = flatten(hparams)
        self.log_dir = Path(self.logger.log_dir)

    def log(self, metrics: dict[str, Any], step: int) -> None:
        self.logger.log_metrics(scalars(metrics), step=step)

    def close(self, summary: dict[str, Any] | None = None) -> None:
        writer = self.logger.experiment
        # run_name="." keeps the hparams in this run's folder (torch makes a sub-run otherwise).
        writer.add_hparams(self.hparams, {f"hparam/{k}": v for k, v in scalars(summary or {}).items()},
                           run_name=".")  # fmt: skip
        writer.close()


def wandb_key_available(environ: dict[str, str] | None = None, home: Path | None = None) -> bool:
    """A W&B API key in the environment, or a ``.netrc`` entry for the W&B host itself."""
    environ = os.environ if environ is None else environ
    if environ.get("WANDB_API_KEY"):
        return True
    host = urlparse(environ.get("WANDB_BASE_URL") or WANDB_HOST).hostname
    path = (home or Path.home()) / ".netrc"
    try:
        entry = netrc.netrc(str(path)).authenticators(host) if path.is_file() else None
    except (netrc.NetrcParseError, OSError):
        return False
    return bool(entry and entry[2])


def wandb_mode(mode: str | None, environ: dict[str, str] | None = None, home: Path | None = None) -> str | None:
    """``logger.mode`` if set; None (wandb reads ``WANDB_MODE``) when that variable is set;
    else online with a key, offline without."""
    environ = os.environ if environ is None else environ
    if mode:
        return mode
    if environ.get("WANDB_MODE"):
        return None
    return "online" if wandb_key_available(environ, home) else "offline"


class WandbLogger(MetricLogger):
    """Weights & Biases; see the module doc for when it is online.

    wandb itself, not torchrl's WandbLogger: that one sets ``WANDB_MODE`` for the whole process
    when offline and adds a step column per metric group.
    """

    def __init__(self, run_dir: Path, project: str, config: dict[str, Any], mode: str | None, name: str | None = None):
        try:
            import wandb
        except ImportError as err:  # an optional extra (scripts/setup.sh installs it)
            raise ImportError("logger=wandb needs wandb: pip install wandb") from err
        mode = wandb_mode(mode)
        kwargs = dict(project=project, dir=str(run_dir), config=config, name=name or Path(run_dir).name)
        try:
            self.run = wandb.init(mode=mode, **kwargs)
        except Exception as err:  # noqa: BLE001 - no key, a bad key, no network: log offline instead
            if mode == "offline":
                raise
            log.warning("wandb could not go online (%s: %s); logging offline in %s (upload later "
                        "with `wandb sync`)", type(err).__name__, str(err).splitlines()[0], run_dir)  # fmt: skip
            self.run = wandb.init(mode="offline", **kwargs)
        self.mode = self.run.settings.mode
        log.info("wandb logging %s (project %s) in %s", self.mode, project, run_dir)

    def log(self, metrics: dict[str, Any], step: int) -> None:
        self.run.log({**scalars(metrics), "step": step}, step=step)

    def close(self, summary: dict[str, Any] | None = None) -> None:
        if summary:
            self.run.summary.update(scalars(summary))
        self.run.finish()


class HistoryLogger:
    """Forwards the rows a job appends to a history list (``{"step": ..., metric: value}``) to a
    logger: each ``flush()`` logs the rows added since the last one, at their own step."""

    def __init__(self, logger: MetricLogger, history: list[dict[str, Any]],
                 rename: Any = None) -> None:
        self.logger, self.history, self.logged = logger, history, 0
        self.rename = rename or (lambda key: key)  # a row's key -> the logged tag

    def flush(self) -> None:
        for row in self.history[self.logged :]:
            self.logger.log({self.rename(k): v for k, v in row.items() if k != "step"},
                            int(row.get("step", self.logged)))
            self.logged += 1


_EPOCH_TAGS = {"train_loss": "train/loss", "train_accuracy": "train/accuracy", "lr": "train/lr",
               "epoch_time": "time/epoch_s", "clips_per_s": "time/clips_per_s"}


def epoch_tag(key: str) -> str:
    """A recognition epoch's key as the tag Lightning users know: ``train/loss``,
    ``train/accuracy``, ``train/lr``, ``val/accuracy``, ``val/mcc`` (``val/<metric>``),
    ``time/epoch_s``, ``time/clips_per_s``."""
    return _EPOCH_TAGS.get(key) or (f"val/{key[4:]}" if key.startswith("val_") else key)


_PPO_TIME = {"seconds", "env_steps_per_s", "steps_per_s"}


def ppo_tag(key: str) -> str:
    """A PPO history key as the tag SB3 users know: ``rollout/`` (training episodes' reward and
    terms), ``eval/`` (evaluations), ``train/`` (losses, KL, log std, learning rate), ``time/``
    (seconds, steps per second), ``counts/`` (NaN actions, divergences, early ends)."""
    if key in _PPO_TIME:
        return f"time/{key}"
    if key.startswith("train_"):
        return f"rollout/{key[6:]}"
    if key.startswith("eval_"):
        return f"eval/{key[5:]}"
    if key == "last_eval":
        return "eval/last"
    if key.startswith("count_"):
        return f"counts/{key[6:]}"
    return f"train/{key}"


def make_logger(cfg: dict[str, Any], run_dir: Path, run_config: dict[str, Any]) -> MetricLogger:
    """The logger named by ``cfg['name']``, writing into ``run_dir``; ``run_config`` is logged as
    the run's hyper-parameters."""
    name = cfg.get("name", "none")
    if name == "none":
        return MetricLogger()
    if name == "csv":
        return CsvLogger(run_dir)
    if name == "tensorboard":
        return TensorBoardLogger(run_dir, run_config)
    if name == "wandb":
        return WandbLogger(run_dir, cfg.get("project", "aslexp"), run_config, cfg.get("mode"))
    raise ValueError(f"logger.name={name!r}: expected one of {', '.join(LOGGERS)}")
