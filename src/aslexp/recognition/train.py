"""Training: validation (early stopping or a fixed budget), the final retrain, checkpoints.

Two entry points, both for torch and scikit-learn classifiers:

* :func:`fit` trains on ``train``, evaluates on ``val`` after each epoch, keeps the state of the
  epoch with the best validation score (``selection_metric``), stops after ``patience`` epochs
  without improvement and restores the best state (or trains ``max_epochs`` and keeps the last).
  ``on_epoch_end(epoch, val_score)`` runs after every epoch; whatever it raises (e.g.
  ``optuna.TrialPruned``) propagates unchanged.
* :func:`fit_final` trains a fresh classifier on ``train+val`` for a fixed number of epochs (the
  best epoch count :func:`fit` found) and predicts the test set once.

scikit-learn classifiers have no epochs: ``fit`` is one "epoch" that fits and evaluates.
Torch models train on ``device`` (the arrays are moved there once) with optional autocast, SGD or
Adam, warm-up and step/multi-step schedules, and training-time augmentation (augment.py); a module
with ``on_epoch_start(epoch_index)`` gets it called before every epoch (SL-GCN's schedules).
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

from aslexp.config_schema import TRAINER, read
from aslexp.data.dataset import RecognitionDataset
from aslexp.recognition.augment import pad_frames, random_shift, random_temporal_crop
from aslexp.recognition.device import autocast, check_precision, resolve_device
from aslexp.recognition.metrics import mcc, selection_score
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
# ``on_epoch_record(epoch, record)``: every number of the epoch (loss, accuracies, lr, timing).
RecordCallback = Callable[[int, dict], None]
CHECKPOINT_FORMAT = "aslexp.recognition.checkpoint/1"


@dataclass(frozen=True)
class TrainerConfig:
    """Training settings (the keys of conf/trainer/*.yaml).

    optimizer:             adam | sgd (momentum, nesterov: SGD only).
    lr, weight_decay:      the base learning rate and L2 weight decay (every parameter, as SL-GCN).
    lr_schedule:           step: multiply by lr_gamma every lr_step_size epochs (StepLR);
                           multistep: multiply by lr_gamma at each of lr_milestones (epochs,
                           0-based as SL-GCN's ``step``); none: constant.
    warmup_epochs:         linear warm-up over the first epochs, lr * (e + 1) / warmup_epochs for
                           e = 0 .. warmup_epochs - 1 (SL-GCN's ``warm_up_epoch``).
    batch_size, max_epochs: mini-batches per epoch and the epoch budget; drop_last drops a last
                           incomplete batch (SL-GCN's loader), else a last batch of one clip joins
                           the previous one (BatchNorm cannot train on one item).
    early_stopping, patience, min_delta: stop after ``patience`` epochs whose validation score did
                           not beat the best by more than ``min_delta`` and restore the best state;
                           without early stopping every run trains ``max_epochs`` epochs and the
                           last epoch is the validated one (thesis ch. 3: 50 epochs).
    selection_metric:      the validation score that early stopping, the best epoch and the
                           objective use: mcc (thesis ch. 4) | f1_micro (thesis ch. 3) | f1_macro |
                           accuracy | balanced_accuracy.
    retrain_epochs:        the epoch budget of the final retrain on train+val: best (the median
                           over folds of the best epoch) | smoothed (the median over folds of the
                           best epoch of the validation curve smoothed over ``smoothing_window``
                           epochs: a single lucky early epoch cannot set the budget).
    final_retrain:         retrain on train+val before testing; if false, test the validated
                           (early-stopped) model trained on train only.
    class_weights:         weigh the loss by inverse class frequency in the training set.
    crop_window:           random temporal crop of this many frames during training (0 = off;
                           SL-GCN: 100). Models with a fixed input length get the crop padded back.
    shift, shift_channels: random per-clip offset in [-shift, shift) added to these channels of the
                           observed keypoints during training (0 = off; SL-GCN's random shift).
    device:                auto | cpu | cuda | cuda:<i>; precision: 32 | bf16 | fp16 (autocast).
    data_on_device:        hold the training arrays on the device (one copy per run) instead of
                           moving every batch.
    num_threads:           torch.set_num_threads (the machine's cores are shared: keep small).
    deterministic:         torch's deterministic kernels, warnings only (aslexp.seeding; cheap on CPU).
    eval_batch_size:       batch size for validation/test inference.
    """

    optimizer: str = "adam"
    lr: float = 1e-3
    weight_decay: float = 1e-4
    momentum: float = 0.9
    nesterov: bool = False
    lr_schedule: str = "step"
    lr_step_size: int = 20
    lr_gamma: float = 0.5
    lr_milestones: tuple[int, ...] = ()
    warmup_epochs: int = 0
    batch_size: int = 32
    drop_last: bool = False
    max_epochs: int = 50
    early_stopping: bool = True
    patience: int = 10
    min_delta: float = 0.0
    selection_metric: str = "mcc"
    retrain_epochs: str = "best"
    smoothing_window: int = 5
    final_retrain: bool = True
    class_weights: bool = False
    crop_window: int = 0
    shift: float = 0.0
    shift_channels: tuple[int, ...] = (0, 1)
    device: str = "auto"
    precision: str = "32"
    data_on_device: bool = True
    num_threads: int = 2
    deterministic: bool = True
    eval_batch_size: int = 128

    @classmethod
    def parse(cls, values: Mapping[str, Any] | TrainerConfig | None, section: str = "trainer") -> TrainerConfig:
        """Types, ranges and choices: aslexp.config_schema.TRAINER (the recognize job checks the
        same before anything runs); a TrainerConfig is taken as it is."""
        if isinstance(values, TrainerConfig):
            return values
        return read(cls, values, section, TRAINER)

    def to_dict(self) -> dict[str, Any]:
        values = dataclasses.asdict(self)
        values.update(lr_milestones=list(self.lr_milestones), shift_channels=list(self.shift_channels))
        return values


OPTIMIZERS = TRAINER["optimizer"].choices
LR_SCHEDULES = TRAINER["lr_schedule"].choices
SELECTION_METRICS = TRAINER["selection_metric"].choices
RETRAIN_BUDGETS = TRAINER["retrain_epochs"].choices


def learning_rate(config: TrainerConfig, epoch_index: int) -> float:
    """The learning rate of epoch ``epoch_index`` (0-based): warm-up, then the schedule."""
    if epoch_index < config.warmup_epochs:
        return config.lr * (epoch_index + 1) / config.warmup_epochs
    if config.lr_schedule == "step":
        return config.lr * config.lr_gamma ** (epoch_index // config.lr_step_size)
    if config.lr_schedule == "multistep":
        return config.lr * config.lr_gamma ** sum(epoch_index >= m for m in config.lr_milestones)
    return config.lr


def make_optimizer(module: nn.Module, config: TrainerConfig) -> torch.optim.Optimizer:
    if config.optimizer == "sgd":
        return torch.optim.SGD(module.parameters(), lr=config.lr, momentum=config.momentum,
                               nesterov=config.nesterov, weight_decay=config.weight_decay)  # fmt: skip
    return torch.optim.Adam(module.parameters(), lr=config.lr, weight_decay=config.weight_decay)


def smoothed_best_epoch(history: list[dict[str, float]], key: str, window: int) -> int:
    """1-based epoch of the maximum of ``key`` smoothed by a centred moving average of ``window``
    epochs (shrinking at the ends); NaN scores count as -inf."""
    values = np.array([row.get(key, math.nan) for row in history], dtype=np.float64)
    if len(values) == 0:
        return 1
    values = np.where(np.isfinite(values), values, -np.inf)
    half = window // 2
    smoothed = [np.mean(values[max(0, i - half) : i + half + 1]) for i in range(len(values))]
    return int(np.argmax(smoothed)) + 1


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
             val_accuracy, val_mcc (NaN without validation), val_<selection metric> when that is
             another metric, lr (at the epoch), epoch_time (s), clips_per_s. scikit-learn models
             fit once: one record, plus ``curve`` (see :func:`fit`).
    best_epoch: epoch (1-based) with the best validation score, i.e. the epoch count to retrain for.
    best_val_score: that score (``selection_metric``); best_val_mcc: the MCC at that epoch.
    """

    history: list[dict[str, float]] = field(default_factory=list)
    best_epoch: int = 0
    best_val_score: float = math.nan
    best_val_mcc: float = math.nan
    selection_metric: str = "mcc"
    stopped_early: bool = False
    curve: list[dict[str, float]] = field(default_factory=list)

    @property
    def epochs_run(self) -> int:
        return len(self.history)

    def to_dict(self) -> dict[str, Any]:
        return {
            "history": self.history,
            "best_epoch": self.best_epoch,
            "best_val_score": self.best_val_score,
            "best_val_mcc": self.best_val_mcc,
            "selection_metric": self.selection_metric,
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


def _batches(num_items: int, batch_size: int, rng: np.random.Generator, drop_last: bool = False) -> list[np.ndarray]:
    """Shuffled index batches; a last batch of one item joins the previous one (BatchNorm
    cannot train on a single item) rather than being dropped; ``drop_last`` drops a last
    incomplete batch (never the only one)."""
    order = rng.permutation(num_items)
    batches = [order[start : start + batch_size] for start in range(0, num_items, batch_size)]
    if drop_last and len(batches) > 1 and len(batches[-1]) < batch_size:
        batches.pop()
    elif len(batches) > 1 and len(batches[-1]) == 1:
        last = batches.pop()  # (popping inside the assignment used to overwrite the wrong batch)
        batches[-1] = np.concatenate([batches[-1], last])
    return batches


def _format_seconds(seconds: float) -> str:
    seconds = max(0, int(round(seconds)))
    return f"{seconds // 60}m{seconds % 60:02d}s"


def _evaluate(classifier: Classifier, split: ArraySplit | None, metric: str = "mcc") -> dict[str, float]:
    """Validation accuracy, MCC and the selection score (NaN without a split)."""
    if split is None or len(split) == 0:
        return {"accuracy": math.nan, "mcc": math.nan, "score": math.nan}
    y_pred = classifier.predict(split.X, split.mask)
    result = {"accuracy": float((y_pred == split.y).mean()), "mcc": mcc(split.y, y_pred)}
    result["score"] = result[metric] if metric in result else selection_score(split.y, y_pred, metric)
    return result


def _record(epoch: int, train_loss: float, train_accuracy: float, val: dict[str, float], lr: float,
            epoch_time: float, clips_per_s: float, metric: str) -> dict[str, float]:  # fmt: skip
    record = {"epoch": epoch, "train_loss": train_loss, "train_accuracy": train_accuracy,
              "val_accuracy": val["accuracy"], "val_mcc": val["mcc"]}  # fmt: skip
    if metric not in ("mcc", "accuracy"):
        record[f"val_{metric}"] = val["score"]
    record.update(lr=lr, epoch_time=epoch_time, clips_per_s=clips_per_s)
    return record


LEARNING_CURVE_FRACTIONS = (0.2, 0.4, 0.6, 0.8, 1.0)


def _sklearn_learning_curve(classifier: SklearnClassifier, train: ArraySplit, val: ArraySplit,
                            config: TrainerConfig, seed: int) -> list[dict[str, float]]:  # fmt: skip
    """Train and validation score against the number of training clips: a model fitted once has
    no epochs, so its learning curve is over data (stratified nested subsets of ``train``)."""
    rng = np.random.default_rng(seed)
    members, ranks = [], []
    for label in np.unique(train.y):  # rank each class's clips in (0, 1): every prefix is stratified
        shuffled = rng.permutation(np.flatnonzero(train.y == label))
        members.append(shuffled)
        ranks.append((np.arange(len(shuffled)) + 0.5) / len(shuffled))
    order = np.concatenate(members)[np.argsort(np.concatenate(ranks), kind="stable")]
    curve = []
    for fraction in LEARNING_CURVE_FRACTIONS:
        size = max(int(round(fraction * len(order))), 2)
        subset = order[:size]
        if len(np.unique(train.y[subset])) < 2:
            continue
        probe = copy.deepcopy(classifier)
        part = ArraySplit(train.X[subset], train.mask[subset], train.y[subset])
        probe.fit(part.X, part.mask, part.y, seed=seed, class_weights=config.class_weights)
        fitted = _evaluate(probe, part, config.selection_metric)
        held_out = _evaluate(probe, val, config.selection_metric)
        curve.append({"train_size": size, "train_score": fitted["score"], "val_score": held_out["score"],
                      "train_accuracy": fitted["accuracy"], "val_accuracy": held_out["accuracy"]})  # fmt: skip
    return curve


def _fit_sklearn(
    classifier: SklearnClassifier, train: ArraySplit, val: ArraySplit | None, config: TrainerConfig, seed: int,
    on_epoch_end: EpochCallback | None, learning_curve: bool = False,
    on_epoch_record: RecordCallback | None = None,
) -> FitResult:
    start = time.perf_counter()
    classifier.fit(train.X, train.mask, train.y, seed=seed, class_weights=config.class_weights)
    train_eval = _evaluate(classifier, train, config.selection_metric)
    val_eval = _evaluate(classifier, val, config.selection_metric)
    elapsed = time.perf_counter() - start
    record = _record(1, math.nan, train_eval["accuracy"], val_eval, math.nan, elapsed,
                     len(train) / max(elapsed, 1e-9), config.selection_metric)  # fmt: skip
    log.info(
        "%s: fitted on %d clips (%d features) in %.2fs; train acc %.3f, val acc %.3f, val MCC %.3f",
        classifier.name, len(train), classifier.fit_info.num_features, elapsed, train_eval["accuracy"],
        val_eval["accuracy"], val_eval["mcc"],
    )
    result = FitResult(history=[record], best_epoch=1, best_val_score=val_eval["score"], best_val_mcc=val_eval["mcc"],
                       selection_metric=config.selection_metric)  # fmt: skip
    if learning_curve and val is not None:
        result.curve = _sklearn_learning_curve(classifier, train, val, config, seed)
    if on_epoch_record is not None:
        on_epoch_record(1, record)
    if on_epoch_end is not None:
        on_epoch_end(1, val_eval["score"])
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
    on_epoch_record: RecordCallback | None = None,
) -> FitResult:
    device, precision = _learner_device(config)
    module = classifier.module.to(device)
    classifier.eval_batch_size = config.eval_batch_size
    classifier.precision = precision
    optimizer = make_optimizer(module, config)
    scaler = torch.amp.GradScaler("cuda") if precision == "fp16" else None
    loss_fn = _loss(config, train, classifier.spec.num_classes, device)
    data = _TrainingData.of(train, config, device)
    rng = np.random.default_rng(seed)
    augmenting = config.crop_window > 0 or config.shift > 0
    generator = torch.Generator(device=device).manual_seed(seed) if augmenting else None
    on_epoch_start = getattr(module, "on_epoch_start", None)
    metric = config.selection_metric

    result = FitResult(selection_metric=metric)
    best_state: dict[str, torch.Tensor] | None = None
    epochs_without_improvement = 0
    run_start = time.perf_counter()
    for epoch in range(1, epochs + 1):
        epoch_start = time.perf_counter()
        lr = learning_rate(config, epoch - 1)
        for group in optimizer.param_groups:
            group["lr"] = lr
        if on_epoch_start is not None:
            on_epoch_start(epoch - 1)
        module.train()
        loss_sum, correct, seen = 0.0, 0, 0
        for batch in _batches(len(train), config.batch_size, rng, config.drop_last):
            x, m, y = data.batch(batch, device)
            if generator is not None:
                x, m = _augment(x, m, config, generator, getattr(module, "fixed_length", False))
            with autocast(device, precision):
                logits = module(x, m)
                loss = loss_fn(logits.float(), y)
            _step(optimizer, scaler, loss)
            loss_sum += float(loss.detach()) * len(batch)
            correct += int((logits.detach().argmax(dim=1) == y).sum())
            seen += len(batch)
        train_time = time.perf_counter() - epoch_start
        val_eval = _evaluate(classifier, val, metric)
        epoch_time = time.perf_counter() - epoch_start
        record = _record(epoch, loss_sum / max(seen, 1), correct / max(seen, 1), val_eval, lr, epoch_time,
                         seen / max(train_time, 1e-9), metric)  # fmt: skip
        result.history.append(record)

        score = val_eval["score"]
        improved = early_stopping and (best_state is None or score > result.best_val_score + config.min_delta)
        if improved:
            result.best_epoch, result.best_val_score, result.best_val_mcc = epoch, score, val_eval["mcc"]
            best_state = copy.deepcopy(module.state_dict())
            epochs_without_improvement = 0
        elif early_stopping:
            epochs_without_improvement += 1

        _log_epoch(classifier.name, epoch, epochs, record, val_eval if val is not None else None, metric, improved,
                   (time.perf_counter() - run_start) / epoch)
        if on_epoch_record is not None:
            on_epoch_record(epoch, record)
        if on_epoch_end is not None:
            on_epoch_end(epoch, score)  # may raise (e.g. optuna.TrialPruned): let it propagate
        if early_stopping and epochs_without_improvement >= config.patience:
            result.stopped_early = True
            log.info("%s: early stop after epoch %d (no val %s gain for %d epochs); best epoch %d, val %s %.3f",
                     classifier.name, epoch, metric, config.patience, result.best_epoch, metric, result.best_val_score)
            break

    _end_fit(result, module, best_state, early_stopping, metric)
    return result


def _learner_device(config: TrainerConfig) -> tuple[torch.device, str]:
    """The learner's device and precision (its threads set; cuDNN autotuned unless ``deterministic``)."""
    torch.set_num_threads(config.num_threads)
    device = resolve_device(config.device)
    precision = check_precision(config.precision, device)
    if device.type == "cuda":  # autotuned convolution kernels, unless bit-reproducibility was asked for
        torch.backends.cudnn.benchmark = not config.deterministic
    return device, precision


def _loss(config: TrainerConfig, train: ArraySplit, num_classes: int, device: torch.device) -> nn.Module:
    """Cross-entropy, weighted by inverse class frequency with ``class_weights``."""
    class_weight = None
    if config.class_weights:
        class_weight = torch.as_tensor(inverse_frequency_weights(train.y, num_classes),
                                       dtype=torch.float32, device=device)  # fmt: skip
    return nn.CrossEntropyLoss(weight=class_weight)


def _end_fit(result: FitResult, module: nn.Module, best_state: dict[str, torch.Tensor] | None, early_stopping: bool,
             metric: str) -> None:
    """The fit's kept weights (the best epoch's with early stopping, else the last's) and their scores."""
    if early_stopping and best_state is not None:
        module.load_state_dict(best_state)
    elif not early_stopping:
        result.best_epoch = result.epochs_run
        if result.history:
            last = result.history[-1]
            result.best_val_score = last.get(f"val_{metric}", last["val_mcc"] if metric == "mcc" else last["val_accuracy"])
            result.best_val_mcc = last["val_mcc"]
    module.eval()


def _log_epoch(name: str, epoch: int, epochs: int, record: dict[str, Any], val_eval: dict[str, Any] | None,
               metric: str, improved: bool, mean_epoch_time: float) -> None:
    """The epoch's progress line: loss, accuracies, learning rate, rate and ETA (``*``: a new best)."""
    validation = f"  val acc {val_eval['accuracy']:.3f}  val MCC {val_eval['mcc']:.3f}" if val_eval is not None else ""
    if val_eval is not None and metric not in ("mcc", "accuracy"):
        validation += f"  val {metric} {val_eval['score']:.3f}"
    log.info(
        "%s epoch %d/%d  loss %.4f  train acc %.3f%s  lr %.2e  %.1f clips/s  %.2fs  ETA <= %s%s",
        name, epoch, epochs, record["train_loss"], record["train_accuracy"], validation,
        record["lr"], record["clips_per_s"], record["epoch_time"], _format_seconds(mean_epoch_time * (epochs - epoch)),
        "  *" if improved else "",
    )


@dataclass
class _TrainingData:
    """The training split as tensors, on the device (``data_on_device``) or in (pinned) host memory."""

    x: torch.Tensor
    mask: torch.Tensor
    y: torch.Tensor
    device: torch.device

    @classmethod
    def of(cls, train: ArraySplit, config: TrainerConfig, device: torch.device) -> "_TrainingData":
        x_all, mask_all = to_tensors(train.X, train.mask)
        y_all = torch.as_tensor(train.y, dtype=torch.long)
        data_device = device if config.data_on_device else torch.device("cpu")
        x_all, mask_all, y_all = x_all.to(data_device), mask_all.to(data_device), y_all.to(data_device)
        if data_device.type == "cpu" and device.type == "cuda":
            x_all, mask_all, y_all = x_all.pin_memory(), mask_all.pin_memory(), y_all.pin_memory()
        return cls(x_all, mask_all, y_all, data_device)

    def batch(self, rows: np.ndarray, device: torch.device) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """The rows' clips, masks and labels on the learner's ``device``."""
        index = torch.from_numpy(rows).to(self.device)
        x, m, y = self.x[index], self.mask[index], self.y[index]
        if self.device != device:
            x, m, y = (t.to(device, non_blocking=True) for t in (x, m, y))
        return x, m, y


def _step(optimizer: torch.optim.Optimizer, scaler, loss: torch.Tensor) -> None:
    """One optimiser step on ``loss`` (through the fp16 gradient scaler when there is one)."""
    optimizer.zero_grad(set_to_none=True)
    if scaler is not None:
        scaler.scale(loss).backward()
        scaler.step(optimizer)
        scaler.update()
    else:
        loss.backward()
        optimizer.step()


def _augment(x: torch.Tensor, mask: torch.Tensor, config: TrainerConfig, generator: torch.Generator,
             fixed_length: bool) -> tuple[torch.Tensor, torch.Tensor]:  # fmt: skip
    length = x.shape[2]
    if 0 < config.crop_window < length:
        x, mask = random_temporal_crop(x, mask, config.crop_window, generator)
        if fixed_length:
            x, mask = pad_frames(x, mask, length)
    if config.shift > 0:
        channels = tuple(c for c in config.shift_channels if c < x.shape[1])
        x = random_shift(x, mask, config.shift, channels, generator)
    return x, mask


def fit(
    classifier: Classifier,
    train: ArraySplit,
    val: ArraySplit,
    config: TrainerConfig | Mapping[str, Any] | None = None,
    *,
    seed: int = 0,
    on_epoch_end: EpochCallback | None = None,
    learning_curve: bool = False,
    on_epoch_record: RecordCallback | None = None,
) -> FitResult:
    """Train ``classifier`` on ``train``, validating on ``val`` after every epoch.

    With ``early_stopping`` (default) the best epoch by ``selection_metric`` is kept and its state
    restored; without, every epoch runs and the last is the validated one. Seeds python/numpy/torch
    with ``seed`` first (build torch classifiers after seeding, too, for reproducible initial
    weights). ``on_epoch_end(epoch, val_score)`` is called after every epoch (once for
    scikit-learn classifiers); an exception it raises ends training and propagates to the caller.
    ``on_epoch_record(epoch, record)`` gets the epoch's numbers first (loss, accuracies, lr, timing).
    ``learning_curve`` (scikit-learn only) also fits on growing stratified subsets of ``train``
    and keeps train/validation scores per size in ``FitResult.curve``.
    """
    config = TrainerConfig.parse(config)
    if len(train) == 0 or len(val) == 0:
        raise ValueError(f"fit needs non-empty train and val splits, got {len(train)} and {len(val)} clips")
    seed_everything(seed, config.deterministic)
    if isinstance(classifier, SklearnClassifier):
        return _fit_sklearn(classifier, train, val, config, seed, on_epoch_end, learning_curve, on_epoch_record)
    if isinstance(classifier, TorchClassifier):
        return _train_torch(classifier, train, val, config, seed, config.max_epochs, config.early_stopping, on_epoch_end,
                            on_epoch_record)
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
    config = TrainerConfig.parse(config)
    if len(train) == 0:
        raise ValueError("fit_final needs a non-empty training split")
    seed_everything(seed, config.deterministic)
    if isinstance(classifier, SklearnClassifier):
        start = time.perf_counter()
        classifier.fit(train.X, train.mask, train.y, seed=seed, class_weights=config.class_weights)
        train_accuracy = _evaluate(classifier, train)["accuracy"]
        no_val = {"accuracy": math.nan, "mcc": math.nan, "score": math.nan}
        record = _record(1, math.nan, train_accuracy, no_val, math.nan, time.perf_counter() - start, math.nan,
                         config.selection_metric)  # fmt: skip
        fit_result = FitResult(history=[record], best_epoch=1, selection_metric=config.selection_metric)
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
        payload["state_dict"] = {key: value.detach().cpu() for key, value in classifier.module.state_dict().items()}
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
    classifier = rebuild_classifier(ClassifierSpec.from_saved(payload["spec"]))
    assert isinstance(classifier, TorchClassifier)
    classifier.module.load_state_dict(payload["state_dict"])
    classifier.module.eval()
    return classifier, payload["extra"]
