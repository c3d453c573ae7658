"""Training: early stopping on validation MCC, the final retrain, checkpoints.

Two entry points, both for torch and scikit-learn classifiers:

* :func:`fit` trains on ``train``, evaluates on ``val`` after each epoch, keeps the state of the
  epoch with the best validation MCC, stops after ``patience`` epochs without improvement and
  restores the best state. ``on_epoch_end(epoch, val_mcc)`` runs after every epoch; whatever it
  raises (e.g. ``optuna.TrialPruned``) propagates unchanged.
* :func:`fit_final` trains a fresh classifier on ``train+val`` for a fixed number of epochs (the
  best epoch count :func:`fit` found) and predicts the test set once.

scikit-learn classifiers have no epochs: ``fit`` is one "epoch" that fits and evaluates.
"""

from __future__ import annotations

import copy
import dataclasses
import logging
import math
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import joblib
import numpy as np
import torch
from torch import nn

from aslexp.data.dataset import RecognitionDataset
from aslexp.recognition.metrics import mcc
from aslexp.seeding import seed_everything
from aslexp.recognition.models import (
    Classifier,
    ClassifierSpec,
    SklearnClassifier,
    TorchClassifier,
    rebuild_classifier,
    to_tensors,
)

log = logging.getLogger(__name__)

EpochCallback = Callable[[int, float], None]
CHECKPOINT_FORMAT = "aslexp.recognition.checkpoint/1"


@dataclass(frozen=True)
class TrainerConfig:
    """Training settings (the keys of conf/trainer/*.yaml).

    lr, weight_decay:      Adam.
    lr_step_size, lr_gamma: StepLR: multiply the learning rate by lr_gamma every lr_step_size epochs.
    batch_size, max_epochs: mini-batches per epoch and the epoch budget.
    patience, min_delta:   early stopping: stop after ``patience`` epochs whose val MCC did not
                           beat the best by more than ``min_delta``.
    class_weights:         weigh the loss by inverse class frequency in the training set.
    num_threads:           torch.set_num_threads (the machine's cores are shared: keep small).
    deterministic:         torch.use_deterministic_algorithms(warn_only=True) (cheap on CPU).
    eval_batch_size:       batch size for validation/test inference.
    final_retrain:         retrain on train+val for the best epoch count before testing; if
                           false, test the early-stopped model trained on train only.
    """

    lr: float = 1e-3
    weight_decay: float = 1e-4
    lr_step_size: int = 20
    lr_gamma: float = 0.5
    batch_size: int = 32
    max_epochs: int = 50
    patience: int = 10
    min_delta: float = 0.0
    class_weights: bool = False
    num_threads: int = 2
    deterministic: bool = True
    eval_batch_size: int = 128
    final_retrain: bool = True

    @classmethod
    def from_dict(cls, values: Mapping[str, Any] | TrainerConfig | None) -> TrainerConfig:
        """Config from a plain dict; unknown keys raise ValueError naming the accepted ones."""
        if isinstance(values, TrainerConfig):
            return values
        values = dict(values or {})
        accepted = {f.name: f for f in dataclasses.fields(cls)}
        unknown = sorted(set(values) - set(accepted))
        if unknown:
            raise ValueError(f"trainer: unknown keys {unknown}; accepted: {sorted(accepted)}")
        converted = {}
        for key, value in values.items():
            kind = type(accepted[key].default)
            if kind is int and float(value) != int(float(value)):
                raise ValueError(f"trainer: {key} must be an integer, got {value!r}")
            converted[key] = bool(value) if kind is bool else kind(float(value)) if kind is int else kind(value)
        config = cls(**converted)
        for key in ("batch_size", "max_epochs", "lr_step_size", "num_threads", "eval_batch_size"):
            if getattr(config, key) < 1:
                raise ValueError(f"trainer: {key} must be >= 1, got {getattr(config, key)}")
        if config.patience < 1:
            raise ValueError(f"trainer: patience must be >= 1, got {config.patience}")
        return config

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


@dataclass
class ArraySplit:
    """The arrays of one split: X (N, C, T, V, 1), mask (N, T, V), y (N,)."""

    X: np.ndarray
    mask: np.ndarray
    y: np.ndarray

    def __post_init__(self) -> None:
        if not (len(self.X) == len(self.mask) == len(self.y)):
            raise ValueError(f"split arrays differ in length: X {len(self.X)}, mask {len(self.mask)}, y {len(self.y)}")

    def __len__(self) -> int:
        return len(self.y)

    @classmethod
    def from_dataset(cls, dataset: RecognitionDataset, indices: np.ndarray | list[int]) -> ArraySplit:
        indices = np.asarray(indices, dtype=np.int64)
        return cls(dataset.X[indices], dataset.mask[indices], dataset.y[indices])


@dataclass
class FitResult:
    """What :func:`fit` / :func:`fit_final` learnt about the run.

    history: one dict per epoch: epoch, train_loss, train_accuracy (running, during the epoch),
             val_accuracy, val_mcc (NaN without validation), lr (at the epoch), epoch_time (s),
             clips_per_s.
    best_epoch: epoch (1-based) with the best val MCC, i.e. the epoch count to retrain for.
    """

    history: list[dict[str, float]] = field(default_factory=list)
    best_epoch: int = 0
    best_val_mcc: float = math.nan
    stopped_early: bool = False

    @property
    def epochs_run(self) -> int:
        return len(self.history)

    def to_dict(self) -> dict[str, Any]:
        return {
            "history": self.history,
            "best_epoch": self.best_epoch,
            "best_val_mcc": self.best_val_mcc,
            "stopped_early": self.stopped_early,
            "epochs_run": self.epochs_run,
        }


@dataclass
class FinalResult:
    """The final retrain and its one test: ``y_pred`` and ``proba`` over the test split."""

    fit: FitResult
    y_pred: np.ndarray
    proba: np.ndarray


def inverse_frequency_weights(y: np.ndarray, num_classes: int) -> np.ndarray:
    """w_c = n / (k * n_c) over the k classes present (sklearn's 'balanced'); 0 for absent classes."""
    counts = np.bincount(np.asarray(y, dtype=np.int64), minlength=num_classes).astype(np.float64)
    present = counts > 0
    weights = np.zeros(num_classes)
    weights[present] = counts.sum() / (present.sum() * counts[present])
    return weights


def _batches(num_items: int, batch_size: int, rng: np.random.Generator) -> list[np.ndarray]:
    """Shuffled index batches; a last batch of one item joins the previous one (BatchNorm
    cannot train on a single item) rather than being dropped."""
    order = rng.permutation(num_items)
    batches = [order[start : start + batch_size] for start in range(0, num_items, batch_size)]
    if len(batches) > 1 and len(batches[-1]) == 1:
        batches[-2] = np.concatenate([batches[-2], batches.pop()])
    return batches


def _format_seconds(seconds: float) -> str:
    seconds = max(0, int(round(seconds)))
    return f"{seconds // 60}m{seconds % 60:02d}s"


def _evaluate(classifier: Classifier, split: ArraySplit | None) -> tuple[float, float]:
    if split is None or len(split) == 0:
        return math.nan, math.nan
    y_pred = classifier.predict(split.X, split.mask)
    return float((y_pred == split.y).mean()), mcc(split.y, y_pred)


def _fit_sklearn(
    classifier: SklearnClassifier, train: ArraySplit, val: ArraySplit | None, config: TrainerConfig, seed: int,
    on_epoch_end: EpochCallback | None,
) -> FitResult:
    start = time.perf_counter()
    classifier.fit(train.X, train.mask, train.y, seed=seed, class_weights=config.class_weights)
    train_accuracy, _ = _evaluate(classifier, train)
    val_accuracy, val_mcc = _evaluate(classifier, val)
    elapsed = time.perf_counter() - start
    record = {
        "epoch": 1, "train_loss": math.nan, "train_accuracy": train_accuracy, "val_accuracy": val_accuracy,
        "val_mcc": val_mcc, "lr": math.nan, "epoch_time": elapsed, "clips_per_s": len(train) / max(elapsed, 1e-9),
    }
    log.info(
        "%s: fitted on %d clips (%d features) in %.2fs; train acc %.3f, val acc %.3f, val MCC %.3f",
        classifier.name, len(train), classifier.fit_info.num_features, elapsed, train_accuracy, val_accuracy, val_mcc,
    )
    result = FitResult(history=[record], best_epoch=1, best_val_mcc=val_mcc)
    if on_epoch_end is not None:
        on_epoch_end(1, val_mcc)
    return result


def _train_torch(
    classifier: TorchClassifier,
    train: ArraySplit,
    val: ArraySplit | None,
    config: TrainerConfig,
    seed: int,
    epochs: int,
    early_stopping: bool,
    on_epoch_end: EpochCallback | None,
) -> FitResult:
    torch.set_num_threads(config.num_threads)
    module = classifier.module
    classifier.eval_batch_size = config.eval_batch_size
    optimizer = torch.optim.Adam(module.parameters(), lr=config.lr, weight_decay=config.weight_decay)
    scheduler = torch.optim.lr_scheduler.StepLR(optimizer, step_size=config.lr_step_size, gamma=config.lr_gamma)
    class_weight = None
    if config.class_weights:
        class_weight = torch.as_tensor(inverse_frequency_weights(train.y, classifier.spec.num_classes), dtype=torch.float32)
    loss_fn = nn.CrossEntropyLoss(weight=class_weight)
    x_all, mask_all = to_tensors(train.X, train.mask)
    y_all = torch.as_tensor(train.y, dtype=torch.long)
    rng = np.random.default_rng(seed)

    result = FitResult()
    best_state: dict[str, torch.Tensor] | None = None
    epochs_without_improvement = 0
    run_start = time.perf_counter()
    for epoch in range(1, epochs + 1):
        epoch_start = time.perf_counter()
        lr = optimizer.param_groups[0]["lr"]
        module.train()
        loss_sum, correct, seen = 0.0, 0, 0
        for batch in _batches(len(train), config.batch_size, rng):
            index = torch.from_numpy(batch)
            logits = module(x_all[index], mask_all[index])
            loss = loss_fn(logits, y_all[index])
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            optimizer.step()
            loss_sum += float(loss.detach()) * len(batch)
            correct += int((logits.detach().argmax(dim=1) == y_all[index]).sum())
            seen += len(batch)
        scheduler.step()
        train_time = time.perf_counter() - epoch_start
        val_accuracy, val_mcc = _evaluate(classifier, val)
        epoch_time = time.perf_counter() - epoch_start
        record = {
            "epoch": epoch, "train_loss": loss_sum / max(seen, 1), "train_accuracy": correct / max(seen, 1),
            "val_accuracy": val_accuracy, "val_mcc": val_mcc, "lr": lr, "epoch_time": epoch_time,
            "clips_per_s": seen / max(train_time, 1e-9),
        }
        result.history.append(record)

        improved = early_stopping and (best_state is None or val_mcc > result.best_val_mcc + config.min_delta)
        if improved:
            result.best_epoch, result.best_val_mcc = epoch, val_mcc
            best_state = copy.deepcopy(module.state_dict())
            epochs_without_improvement = 0
        elif early_stopping:
            epochs_without_improvement += 1

        mean_epoch_time = (time.perf_counter() - run_start) / epoch
        validation = f"  val acc {val_accuracy:.3f}  val MCC {val_mcc:.3f}" if val is not None else ""
        log.info(
            "%s epoch %d/%d  loss %.4f  train acc %.3f%s  lr %.2e  %.1f clips/s  %.2fs  ETA <= %s%s",
            classifier.name, epoch, epochs, record["train_loss"], record["train_accuracy"], validation,
            lr, record["clips_per_s"], epoch_time, _format_seconds(mean_epoch_time * (epochs - epoch)),
            "  *" if improved else "",
        )
        if on_epoch_end is not None:
            on_epoch_end(epoch, val_mcc)  # may raise (e.g. optuna.TrialPruned): let it propagate
        if early_stopping and epochs_without_improvement >= config.patience:
            result.stopped_early = True
            log.info(
                "%s: early stop after epoch %d (no val MCC gain for %d epochs); best epoch %d, val MCC %.3f",
                classifier.name, epoch, config.patience, result.best_epoch, result.best_val_mcc,
            )
            break

    if early_stopping and best_state is not None:
        module.load_state_dict(best_state)
    elif not early_stopping:
        result.best_epoch = result.epochs_run
    module.eval()
    return result


def fit(
    classifier: Classifier,
    train: ArraySplit,
    val: ArraySplit,
    config: TrainerConfig | Mapping[str, Any] | None = None,
    *,
    seed: int = 0,
    on_epoch_end: EpochCallback | None = None,
) -> FitResult:
    """Train ``classifier`` on ``train`` with early stopping on ``val`` MCC; restore the best state.

    Seeds python/numpy/torch with ``seed`` first (build torch classifiers after seeding, too,
    for reproducible initial weights). ``on_epoch_end(epoch, val_mcc)`` is called after every
    epoch (once for scikit-learn classifiers); an exception it raises ends training and
    propagates to the caller.
    """
    config = TrainerConfig.from_dict(config)
    if len(train) == 0 or len(val) == 0:
        raise ValueError(f"fit needs non-empty train and val splits, got {len(train)} and {len(val)} clips")
    seed_everything(seed, config.deterministic)
    if isinstance(classifier, SklearnClassifier):
        return _fit_sklearn(classifier, train, val, config, seed, on_epoch_end)
    if isinstance(classifier, TorchClassifier):
        return _train_torch(classifier, train, val, config, seed, config.max_epochs, True, on_epoch_end)
    raise TypeError(f"cannot train {type(classifier).__name__}")


def fit_final(
    classifier: Classifier,
    train: ArraySplit,
    test: ArraySplit,
    config: TrainerConfig | Mapping[str, Any] | None = None,
    *,
    epochs: int,
    seed: int = 0,
) -> FinalResult:
    """Train a fresh ``classifier`` on ``train`` (train+val) for exactly ``epochs`` epochs, no
    validation, then predict ``test`` once. ``epochs`` is ignored by scikit-learn classifiers.
    """
    config = TrainerConfig.from_dict(config)
    if len(train) == 0:
        raise ValueError("fit_final needs a non-empty training split")
    seed_everything(seed, config.deterministic)
    if isinstance(classifier, SklearnClassifier):
        start = time.perf_counter()
        classifier.fit(train.X, train.mask, train.y, seed=seed, class_weights=config.class_weights)
        train_accuracy, _ = _evaluate(classifier, train)
        record = {
            "epoch": 1, "train_loss": math.nan, "train_accuracy": train_accuracy, "val_accuracy": math.nan,
            "val_mcc": math.nan, "lr": math.nan, "epoch_time": time.perf_counter() - start, "clips_per_s": math.nan,
        }
        fit_result = FitResult(history=[record], best_epoch=1)
    elif isinstance(classifier, TorchClassifier):
        if epochs < 1:
            raise ValueError(f"fit_final: epochs must be >= 1, got {epochs}")
        fit_result = _train_torch(classifier, train, None, config, seed, epochs, False, None)
    else:
        raise TypeError(f"cannot train {type(classifier).__name__}")
    proba = classifier.predict_proba(test.X, test.mask)
    y_pred = classifier.predict(test.X, test.mask)
    return FinalResult(fit=fit_result, y_pred=y_pred, proba=proba)


# --- Checkpoints ------------------------------------------------------------------------------


def save_checkpoint(classifier: Classifier, path: str | Path, extra: Mapping[str, Any] | None = None) -> Path:
    """Write ``classifier`` to ``path`` (torch: state dict + spec via torch.save, conventionally
    ``model.pt``; scikit-learn: the fitted object via joblib, ``model.joblib``)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    payload: dict[str, Any] = {"format": CHECKPOINT_FORMAT, "kind": classifier.kind, "spec": classifier.spec.to_dict(), "extra": dict(extra or {})}
    if isinstance(classifier, TorchClassifier):
        payload["state_dict"] = classifier.module.state_dict()
        torch.save(payload, path)
    else:
        payload["classifier"] = classifier
        joblib.dump(payload, path)
    return path


def load_checkpoint(path: str | Path) -> tuple[Classifier, dict[str, Any]]:
    """Read a checkpoint written by :func:`save_checkpoint`: (classifier in eval mode, extra)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no checkpoint at {path}")
    if path.suffix == ".joblib":
        payload = joblib.load(path)
    else:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    if not isinstance(payload, dict) or payload.get("format") != CHECKPOINT_FORMAT:
        raise ValueError(f"{path}: not an aslexp recognition checkpoint (expected format {CHECKPOINT_FORMAT!r})")
    if payload["kind"] == "sklearn":
        return payload["classifier"], payload["extra"]
    classifier = rebuild_classifier(ClassifierSpec.from_dict(payload["spec"]))
    assert isinstance(classifier, TorchClassifier)
    classifier.module.load_state_dict(payload["state_dict"])
    classifier.module.eval()
    return classifier, payload["extra"]
