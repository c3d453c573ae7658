"""One recognition experiment: a classifier on a dataset, K splits x S model seeds, one test each.

For every split (``split.repeats`` = K independent seeded splits; K = 1 uses the dataset's own
split) and every model seed:
  1. validation: train on 'train', validate on 'val' (cv5: on each of the 5 folds of 'train+val';
     the run's validation score is the mean over folds, its epoch budget the median over folds of
     the best, or smoothed-best, epoch);
  2. final: retrain a fresh model on 'train+val' for that budget and test once on 'test' (or, with
     ``trainer.final_retrain=false``, test the validated model).
The chance baselines (majority, stratified) run on the same splits; the one with the higher
validation accuracy is *the* baseline (chosen by validation, never by test). The simple baselines
(``simple_baseline``: logreg and rf in the job's default) run as the model does, on the same splits;
the one with the best validation score is the reference of ``comparison`` (the model, the simple
baselines, the chance baseline: test MCC and balanced accuracy, the paired differences). Statistics: the
per-split test metric (mean over model seeds) is the unit; over K splits the report gives mean,
std and a 95% t interval of the mean, and the paired difference to the baseline on the same splits
(t interval and Wilcoxon signed-rank test). With one split the unit is the model seed.

The objective a sweep maximises is ``result["objective"]["value"]`` = the mean validation score
(``trainer.selection_metric``; ``val_mcc`` is always there too); ``on_epoch_end`` receives the
first split's first seed's (first fold's) epochs, for pruning.

Reading order: :func:`run_recognition` plans the run (``_plan``), then per split trains the model
(``_validate``, ``_final_model``), evaluates it (``_record_test``) and runs the baselines beside it;
one tail (``_summarise``, ``_write_outputs``, ``_result_record``) turns what was measured into
statistics, files and metrics.json. The verdict sentence and its cautions are
:mod:`aslexp.recognition.comparison`.
"""

from __future__ import annotations

import csv
import logging
import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from aslexp.data.dataset import RecognitionDataset
from aslexp.data.splits import SplitOptions, resplit
from aslexp.errors import ConfigError
from aslexp.recognition import baseline_cache
from aslexp.recognition.comparison import cautions, comparison_block
from aslexp.recognition.device import check_precision, device_info, resolve_device
from aslexp.recognition.metrics import (
    aggregate_over_seeds,
    classification_metrics,
    mean_interval,
    paired_comparison,
    scalar_metrics,
)
from aslexp.recognition.models import BASELINE_NAMES, Classifier, TorchClassifier, build_classifier, resolve_params
from aslexp.recognition.train import (
    ArraySplit,
    EpochCallback,
    FitResult,
    RecordCallback,
    TrainerConfig,
    fit,
    fit_final,
    save_checkpoint,
    seed_everything,
    smoothed_best_epoch,
)

log = logging.getLogger(__name__)

PER_CLASS_FILE = "per_class.csv"
PREDICTIONS_FILE = "predictions.csv"
CONFUSION_FILE = "confusion_matrix.png"
CURVES_FILE = "learning_curves.png"
# The metrics that get an interval over splits and a paired comparison with the baseline.
KEY_METRICS = ("accuracy", "balanced_accuracy", "mcc", "f1_micro", "f1_macro", "precision_macro", "recall_macro")


def validation_folds(dataset: RecognitionDataset) -> list[tuple[np.ndarray, np.ndarray]]:
    """(train, val) index pairs: [('train', 'val')] for a hold-out split, the 5 folds for cv5.

    Fold indices are dataset row indices (as every other split) and must lie in 'train+val'.
    """
    splits = dataset.splits
    missing = [name for name in ("train+val", "test") if name not in splits]
    if "folds" not in splits:
        missing += [name for name in ("train", "val") if name not in splits]
    if missing:
        raise ValueError(f"dataset '{dataset.property}': splits lack {missing} (have {sorted(splits)})")
    if "folds" not in splits:
        return [(np.asarray(splits["train"], dtype=np.int64), np.asarray(splits["val"], dtype=np.int64))]
    train_val = set(np.asarray(splits["train+val"]).tolist())
    folds = []
    for number, (train_idx, val_idx) in enumerate(splits["folds"]):
        train_idx, val_idx = np.asarray(train_idx, dtype=np.int64), np.asarray(val_idx, dtype=np.int64)
        outside = (set(train_idx.tolist()) | set(val_idx.tolist())) - train_val
        if outside:
            raise ValueError(
                f"dataset '{dataset.property}': fold {number} has {len(outside)} indices outside 'train+val' "
                "(fold indices must be dataset row indices within 'train+val')"
            )
        folds.append((train_idx, val_idx))
    if not folds:
        raise ValueError(f"dataset '{dataset.property}': 'folds' is empty")
    return folds


def split_views(dataset: RecognitionDataset, options: SplitOptions) -> list[tuple[int, RecognitionDataset]]:
    """(split seed, dataset view) per split: the dataset itself when its own split is the one to
    use, else ``options.repeats`` views re-split with seeds ``options.seed + k`` (on one clip per
    gloss when asked). Every view has the same label names (rare classes depend on counts only)."""
    if not options.rebuilds:
        return [(int(options.seed), dataset)]
    labels = [dataset.label_names[int(y)] for y in dataset.y]
    views = []
    for k in range(int(options.repeats)):
        seed = int(options.seed) + k
        result = resplit(labels, dataset.glosses, options, seed)
        keep = result.keep
        view = RecognitionDataset(
            property=dataset.property, label_names=list(result.label_names), X=dataset.X[keep],
            mask=dataset.mask[keep], y=result.y, video_ids=[dataset.video_ids[i] for i in keep],
            glosses=[dataset.glosses[i] for i in keep], signer_ids=[dataset.signer_ids[i] for i in keep],
            layout=dataset.layout, channels=list(dataset.channels), splits=result.splits,
            skipped={**dataset.skipped, "resplit_dropped": int(result.dropped)},
        )
        if views and view.label_names != views[0][1].label_names:
            raise ValueError(f"split seed {seed} kept labels {view.label_names}, seed {views[0][0]} kept "
                             f"{views[0][1].label_names}: repeated splits must share their classes")  # fmt: skip
        views.append((seed, view))
    return views


def _build(dataset: RecognitionDataset, name: str, params: Mapping[str, Any]):
    _, channels, frames, nodes, _ = dataset.X.shape
    return build_classifier(name, dict(params), channels, frames, nodes, dataset.num_classes, dataset.layout)


def _retrain_budget(results: Sequence[FitResult], config: TrainerConfig) -> tuple[int, list[int]]:
    """The final retrain's epoch count: median over folds of each fold's best epoch (``best``) or
    of the best epoch of its smoothed validation curve (``smoothed``)."""
    if config.retrain_epochs == "smoothed" and config.early_stopping:
        key = "val_mcc" if config.selection_metric == "mcc" else f"val_{config.selection_metric}"
        per_fold = [smoothed_best_epoch(r.history, key, config.smoothing_window) for r in results]
    else:
        per_fold = [r.best_epoch for r in results]
    return max(1, int(round(float(np.median(per_fold))))), per_fold


def _baseline_runs(view: RecognitionDataset, folds, train_val: ArraySplit, test: ArraySplit, config: TrainerConfig,
                   seeds: Sequence[int]) -> dict[str, dict[str, list]]:  # fmt: skip
    """Per baseline: validation accuracy (fit on the first fold's train, scored on its val) and the
    test metrics (fit on train+val) for every seed of this split."""
    train_idx, val_idx = folds[0]
    train, val = ArraySplit.from_dataset(view, train_idx), ArraySplit.from_dataset(view, val_idx)
    runs: dict[str, dict[str, list]] = {}
    for name in BASELINE_NAMES:
        runs[name] = {"val_accuracy": [], "test": []}
        for seed in seeds:
            validated = fit(_build(view, name, {}), train, val, config, seed=seed)
            runs[name]["val_accuracy"].append(validated.history[0]["val_accuracy"])
            final = fit_final(_build(view, name, {}), train_val, test, config, epochs=1, seed=seed)
            runs[name]["test"].append(classification_metrics(test.y, final.y_pred, view.label_names))
    return runs


@dataclass(frozen=True)
class _Plan:
    """What a run fixes before it trains: the model, the trainer, the seeds, the simple baselines
    and where its files go."""

    name: str
    params: dict[str, Any]
    config: TrainerConfig
    seeds: list[int]
    out_dir: Path
    simple_params: dict[str, dict[str, Any]]
    simple_same: dict[str, bool]  # the simple baseline that is the model itself: not run twice
    simple_cache: str | Path | None = None
    on_epoch_end: EpochCallback | None = None
    on_epoch_record: RecordCallback | None = None

    @property
    def metric(self) -> str:
        return self.config.selection_metric


@dataclass
class _Runs:
    """What the runs measured, split by split: the input of the statistics and of the files."""

    simple_names: Sequence[str]
    val_records: list[dict[str, Any]] = field(default_factory=list)
    histories: dict[str, list[dict[str, float]]] = field(default_factory=dict)
    final_histories: dict[str, list[dict[str, float]]] = field(default_factory=dict)
    test_runs: list[dict[str, Any]] = field(default_factory=list)  # full metrics per (split, seed)
    per_split: list[dict[str, float]] = field(default_factory=list)  # scalar metrics per split, mean over seeds
    split_records: list[dict[str, Any]] = field(default_factory=list)
    prediction_rows: list[dict[str, Any]] = field(default_factory=list)
    baselines: dict[str, dict[str, list]] = field(default_factory=dict)
    simple: dict[str, dict[str, Any]] = field(default_factory=dict)
    checkpoint_name: str | None = None
    num_parameters: int | None = None
    learning_curve: list = field(default_factory=list)
    is_cv: bool = False
    uses_seed: bool = True  # False: the model draws no random number, so its seeds give one result

    def __post_init__(self) -> None:
        self.baselines = {n: {"val_accuracy": [], "test": [], "test_per_split": []} for n in BASELINE_NAMES}
        self.simple = {b: {"val_score": [], "val_mcc": [], "test": [], "test_per_split": [], "from_cache": 0}
                       for b in self.simple_names}  # fmt: skip


@dataclass(frozen=True)
class _SplitData:
    """One split's arrays: the validation folds, train+val and test."""

    index: int
    seed: int
    view: RecognitionDataset
    folds: list[tuple[np.ndarray, np.ndarray]]
    train_val: ArraySplit
    test_idx: np.ndarray
    test: ArraySplit

    @classmethod
    def of(cls, index: int, seed: int, view: RecognitionDataset) -> _SplitData:
        test_idx = np.asarray(view.splits["test"], dtype=np.int64)
        if len(test_idx) == 0:
            raise ValueError(f"dataset '{view.property}': the 'test' split of split seed {seed} is empty")
        return cls(index, seed, view, validation_folds(view), ArraySplit.from_dataset(view, view.splits["train+val"]),
                   test_idx, ArraySplit.from_dataset(view, test_idx))  # fmt: skip

    @property
    def sizes(self) -> dict[str, int]:
        train, val = self.folds[0]
        return {"train": int(len(train)), "val": int(len(val)), "train+val": len(self.train_val), "test": len(self.test)}


def run_recognition(
    dataset: RecognitionDataset,
    classifier: Mapping[str, Any],
    trainer: Mapping[str, Any] | None,
    seeds: Sequence[int],
    out_dir: str | Path,
    on_epoch_end: EpochCallback | None = None,
    split: Mapping[str, Any] | SplitOptions | None = None,
    on_epoch_record: RecordCallback | None = None,
    simple_baseline: str | Sequence[str] | None = None,
    simple_baseline_overrides: Mapping[str, Mapping[str, Any]] | None = None,
    simple_baseline_cache: str | Path | None = None,
) -> dict[str, Any]:
    """Validate, retrain and test ``classifier`` = {"name": ..., "params": {...}} on ``dataset``.

    ``split`` (the ``split`` config group, see :class:`SplitOptions`) asks for repeated splits;
    without it the dataset's own split is the one split. ``params`` are the run's parameters as the
    config gives them (a key left out takes ``conf/classifier/NAME.yaml``'s). Writes per_class.csv,
    predictions.csv, confusion_matrix.png, learning_curves.png and model.pt / model.joblib (the
    first run's final model) into ``out_dir``, and returns a JSON-ready dict (the job writes it as
    metrics.json):

    objective              {"name": "val_<selection metric>", "value": mean over runs}
    val_mcc, val_mcc_std   mean (std) over runs of the validation MCC; val: one record per run
    test, test_std         mean / std over units (splits; the model seeds for one split) of every
                           scalar test metric; test_interval: mean, std, 95% t interval per KEY_METRIC
    test_per_split         per split: the scalar test metrics averaged over the model seeds
    test_per_seed          full :func:`classification_metrics` of every run (+ 'split', 'seed')
    baseline               the baseline chosen by validation accuracy: name, selected_by,
                           val_accuracy (both), test, test_std, test_interval, test_per_split
    baselines              both baselines (test, test_std, test_per_split, val_accuracy)
    paired_vs_baseline     per KEY_METRIC: model minus baseline on the same splits (units)
    below_baseline         per KEY_METRIC: the model's mean is below the baseline's
    simple_baselines       per ``simple_baseline`` name (none: {}): params, val_score, val_per_unit,
                           val_mcc, test, test_std, test_interval, test_per_split, same_as_model (the
                           model itself: its own numbers, not run again)
    comparison             model, strongest simple baseline (by validation score; a tie is named
                           as one) and chance baseline side by side (:func:`comparison_block`), the
                           paired differences, one sentence and the cautions; what the job prints
    seed_changes_result    false when the model draws no random number (logreg with lbfgs, svm,
                           hgb): its seeds give one result on a split
    splits                 per split: index, seed, sizes; statistics_unit: 'split' | 'seed'
    history, final_history per-epoch records of the validation and final runs, by 'seed S'
                           (one split) or 'split K seed S'
    learning_curve         scikit-learn models: score against training-set size (first run)
    device                 where torch models trained (type, name, precision)
    property, classifier, params, trainer, seeds, validation ('holdout'|'cv5'), num_folds,
    split_sizes, label_names, num_parameters, test_confusion_matrix_total, files, time_s
    """
    plan, options = _plan(dataset, classifier, trainer, seeds, out_dir, split, simple_baseline,
                          simple_baseline_overrides, simple_baseline_cache, on_epoch_end, on_epoch_record)  # fmt: skip
    device = resolve_device(plan.config.device)
    device_record = device_info(device, check_precision(plan.config.precision, device))
    views = split_views(dataset, options)
    runs = _Runs([b for b, same in plan.simple_same.items() if not same])
    start = time.perf_counter()
    for split_index, (split_seed, view) in enumerate(views):
        data = _SplitData.of(split_index, split_seed, view)
        runs.is_cv = "folds" in view.splits
        runs.split_records.append({"index": split_index, "seed": split_seed, "sizes": data.sizes, "clips": len(view.y)})
        _log_split(plan, data, len(views))
        _train_and_test_model(plan, runs, data, num_splits=len(views), start=start)
        _run_chance_baselines(plan, runs, data)
        _run_simple_baselines(plan, runs, data)

    summary = _summarise(plan, runs, unit="split" if len(views) > 1 else "seed")
    label_names = list(views[0][1].label_names)
    _write_outputs(plan, runs, dataset.property, label_names, summary["total_matrix"])
    elapsed = time.perf_counter() - start
    log.info(
        "%s on %s: val %s %.3f +- %.3f, test MCC %.3f +- %.3f over %d %s(s) (baseline %s %.3f), %.1fs",
        plan.name, dataset.property, plan.metric, summary["objective"], _std(summary["val_scores"]),
        summary["test"]["mcc"], summary["test_std"]["mcc"], len(summary["units"]), summary["unit"], summary["chosen"],
        summary["baselines"][summary["chosen"]]["test"]["mcc"], elapsed,
    )
    return _result_record(plan, options, dataset, views, runs, summary, device_record, elapsed)


def _plan(dataset: RecognitionDataset, classifier: Mapping[str, Any], trainer: Mapping[str, Any] | None,
          seeds: Sequence[int], out_dir: str | Path, split: Mapping[str, Any] | SplitOptions | None,
          simple_baseline: str | Sequence[str] | None, simple_overrides: Mapping[str, Mapping[str, Any]] | None,
          simple_cache: str | Path | None, on_epoch_end: EpochCallback | None,
          on_epoch_record: RecordCallback | None) -> tuple[_Plan, SplitOptions]:  # fmt: skip
    """The run's inputs read and checked, before anything trains or is written (but ``out_dir``)."""
    if "name" not in classifier:
        raise ValueError(f"classifier config needs a 'name' (got keys {sorted(classifier)})")
    name = str(classifier["name"])
    params = resolve_params(name, classifier.get("params"), classifier.get("module"))  # a module registers it
    config = TrainerConfig.parse(trainer)
    options = split if isinstance(split, SplitOptions) else SplitOptions.parse(split)
    seeds = [int(seed) for seed in seeds]
    if not seeds:
        raise ValueError("run_recognition needs at least one seed")
    if dataset.num_classes < 2:
        raise ValueError(f"dataset '{dataset.property}' has {dataset.num_classes} class(es); need >= 2")
    simple_params = simple_baseline_params(simple_baseline, simple_overrides)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    plan = _Plan(name, params, config, seeds, out_dir, simple_params,
                 {b: b == name and p == params for b, p in simple_params.items()}, simple_cache, on_epoch_end,
                 on_epoch_record)  # fmt: skip
    return plan, options


def _log_split(plan: _Plan, data: _SplitData, num_splits: int) -> None:
    view, sizes = data.view, data.sizes
    validation = (f"{len(data.folds)}-fold cv" if "folds" in view.splits
                  else f"hold-out (train {sizes['train']}, val {sizes['val']})")  # fmt: skip
    log.info("recognition '%s' on %s, split %d/%d (seed %d): %d classes, X %s, train+val %d, test %d, %s, seeds %s",
             plan.name, view.property, data.index + 1, num_splits, data.seed, view.num_classes, tuple(view.X.shape),
             sizes["train+val"], sizes["test"], validation, plan.seeds)  # fmt: skip


# -- training: validate on the folds, retrain on train+val ---------------------------------------------
def _validate(plan: _Plan, runs: _Runs, data: _SplitData, seed_index: int, seed: int,
              run_key: str) -> tuple[list[FitResult], Classifier]:  # fmt: skip
    """Fit on every fold's train and score on its val (the same initial weights on every fold);
    the first run's first fold feeds the epoch callbacks, the learning curve and the history."""
    results, model = [], None
    for fold_index, (train_idx, val_idx) in enumerate(data.folds):
        seed_everything(seed, plan.config.deterministic)
        model = _build(data.view, plan.name, plan.params)
        first = data.index == 0 and seed_index == 0 and fold_index == 0
        result = fit(
            model, ArraySplit.from_dataset(data.view, train_idx), ArraySplit.from_dataset(data.view, val_idx),
            plan.config, seed=seed, on_epoch_end=plan.on_epoch_end if first else None, learning_curve=first,
            on_epoch_record=plan.on_epoch_record if first else None,
        )
        results.append(result)
        if first:
            runs.learning_curve = result.curve
            runs.uses_seed = model.uses_seed  # asked after the fit: hgb's answer depends on the data's size
        if fold_index == 0:
            runs.histories[run_key] = result.history
    return results, model


def _validation_record(plan: _Plan, data: _SplitData, seed: int, results: Sequence[FitResult], epochs: int,
                       fold_epochs: list[int]) -> dict[str, Any]:  # fmt: skip
    return {
        "split": data.index, "seed": seed, "metric": plan.metric,
        "score": float(np.mean([r.best_val_score for r in results])),
        "mcc": float(np.mean([r.best_val_mcc for r in results])),
        "accuracy": float(np.mean([r.history[r.best_epoch - 1]["val_accuracy"] for r in results])),
        "best_epoch": epochs,
        "fold_best_epochs": [r.best_epoch for r in results],
        "fold_budget_epochs": fold_epochs,
        "fold_score": [r.best_val_score for r in results],
        "fold_mcc": [r.best_val_mcc for r in results],
        "epochs_run": [r.epochs_run for r in results],
        "stopped_early": [r.stopped_early for r in results],
    }


def _final_model(plan: _Plan, runs: _Runs, data: _SplitData, validated: Classifier, epochs: int, seed: int,
                 run_key: str) -> tuple[Classifier, np.ndarray]:  # fmt: skip
    """The model that is tested: retrained on train+val for ``epochs`` from the validation run's
    initial weights (``final_retrain``), else the validated hold-out model; with its test predictions."""
    if plan.config.final_retrain:
        seed_everything(seed, plan.config.deterministic)
        model = _build(data.view, plan.name, plan.params)
        final = fit_final(model, data.train_val, data.test, plan.config, epochs=epochs, seed=seed)
        runs.final_histories[run_key] = final.fit.history
        return model, final.y_pred
    if runs.is_cv:
        raise ValueError("trainer.final_retrain=false needs a hold-out split (cv5 has no single model to test)")
    return validated, validated.predict(data.test.X, data.test.mask)


# -- evaluation: the test, once per run ----------------------------------------------------------------
def _record_test(plan: _Plan, runs: _Runs, data: _SplitData, model: Classifier, y_pred: np.ndarray, seed: int,
                 epochs: int) -> dict[str, Any]:  # fmt: skip
    """The run's test metrics and predictions; the first run's model is the run folder's checkpoint."""
    view = data.view
    metrics = classification_metrics(data.test.y, y_pred, view.label_names)
    metrics.update(split=data.index, seed=seed)
    runs.test_runs.append(metrics)
    for row_index, predicted in zip(data.test_idx, y_pred):
        true = int(view.y[row_index])
        runs.prediction_rows.append({"video_id": view.video_ids[row_index], "true": view.label_names[true],
                                     "predicted": view.label_names[int(predicted)], "split": data.index,
                                     "seed": seed, "correct": int(true == int(predicted))})  # fmt: skip
    if runs.checkpoint_name is None:
        runs.checkpoint_name = "model" + model.checkpoint_suffix
        save_checkpoint(model, plan.out_dir / runs.checkpoint_name,
                        extra={"seed": seed, "split": data.index, "split_seed": data.seed, "epochs": epochs,
                               "label_names": list(view.label_names), "property": view.property})  # fmt: skip
        if isinstance(model, TorchClassifier):
            runs.num_parameters = model.num_parameters()
    return metrics


def _train_and_test_model(plan: _Plan, runs: _Runs, data: _SplitData, num_splits: int, start: float) -> None:
    """The model on one split, for every seed: validate, retrain, test once."""
    split_tests, total_runs = [], num_splits * len(plan.seeds)
    for seed_index, seed in enumerate(plan.seeds):
        run_key = f"seed {seed}" if num_splits == 1 else f"split {data.index} seed {seed}"
        results, validated = _validate(plan, runs, data, seed_index, seed, run_key)
        epochs, fold_epochs = _retrain_budget(results, plan.config)
        runs.val_records.append(_validation_record(plan, data, seed, results, epochs, fold_epochs))
        model, y_pred = _final_model(plan, runs, data, validated, epochs, seed, run_key)
        metrics = _record_test(plan, runs, data, model, y_pred, seed, epochs)
        split_tests.append(metrics)
        log.info("run %d/%d (split %d, seed %d): val %s %.3f (epochs %d) -> test acc %.3f, balanced %.3f, MCC %.3f  "
                 "[%.0fs]", len(runs.test_runs), total_runs, data.index, seed, plan.metric,
                 runs.val_records[-1]["score"], epochs, metrics["accuracy"], metrics["balanced_accuracy"],
                 metrics["mcc"], time.perf_counter() - start)  # fmt: skip
    runs.per_split.append(aggregate_over_seeds(split_tests)[0])


# -- the baselines, on the same split ----------------------------------------------------------------
def _run_chance_baselines(plan: _Plan, runs: _Runs, data: _SplitData) -> None:
    for baseline, measured in _baseline_runs(data.view, data.folds, data.train_val, data.test, plan.config,
                                             plan.seeds).items():  # fmt: skip
        runs.baselines[baseline]["val_accuracy"] += measured["val_accuracy"]
        runs.baselines[baseline]["test"] += measured["test"]
        runs.baselines[baseline]["test_per_split"].append(aggregate_over_seeds(measured["test"])[0])


def _run_simple_baselines(plan: _Plan, runs: _Runs, data: _SplitData) -> None:
    """Each simple baseline that is not the model, run as the model is (or read from the cache)."""
    if not runs.simple:
        return
    view, folds, train_val, test = data.view, data.folds, data.train_val, data.test
    arrays = [view.X, view.mask, view.y, train_val.X, train_val.mask, train_val.y, test.X, test.mask, test.y,
              *(np.asarray(i) for fold in folds for i in fold)]  # fmt: skip
    digest = baseline_cache.data_digest(arrays) if plan.simple_cache else ""
    for baseline, measured in runs.simple.items():
        params = plan.simple_params[baseline]
        key = baseline_cache.cache_key(baseline, params, plan.config, plan.seeds, view.label_names, digest)
        val, tests, reused = baseline_cache.cached(
            plan.simple_cache, key, baseline,
            lambda: _simple_baseline_runs(view, baseline, params, folds, train_val, test, plan.config, plan.seeds))
        measured["from_cache"] += int(reused)
        measured["val_score"] += [v["score"] for v in val]
        measured["val_mcc"] += [v["mcc"] for v in val]
        measured["test"] += tests
        measured["test_per_split"].append(aggregate_over_seeds(tests)[0])
        log.info("simple baseline %s (split %d): val %s %.3f -> test MCC %.3f, balanced %.3f%s", baseline, data.index,
                 plan.metric, float(np.mean([v["score"] for v in val])), measured["test_per_split"][-1]["mcc"],
                 measured["test_per_split"][-1]["balanced_accuracy"],
                 " (measured by an earlier run: simple_baseline_cache)" if reused else "")  # fmt: skip


# -- the shared tail: statistics over units, files, the record -------------------------------------------
def _units(unit: str, per_split: list[dict[str, float]], runs: Sequence[Mapping[str, Any]]) -> list[dict[str, float]]:
    """The statistics' units: one per split (means over seeds), or one per model seed of the one split."""
    return per_split if unit == "split" else [scalar_metrics(m) for m in runs]


def _val_units(unit: str, scores: Sequence[float], num_splits: int) -> list[float]:
    """Per-run validation scores (split-major) as units: per split the mean over seeds, or per seed."""
    values = np.asarray(scores, dtype=np.float64)
    return values.reshape(num_splits, -1).mean(axis=1).tolist() if unit == "split" else values.tolist()


def _summary_of(base_units: list[dict[str, float]]) -> dict[str, Any]:
    mean, std = aggregate_over_seeds(base_units)
    return {"test": mean, "test_std": std, "test_per_split": base_units,
            "test_interval": {key: mean_interval([u[key] for u in base_units]) for key in KEY_METRICS}}  # fmt: skip


def _summarise(plan: _Plan, runs: _Runs, unit: str) -> dict[str, Any]:
    """Every statistic of the record: the model over units, both chance baselines (the better by
    validation accuracy is *the* baseline), the simple baselines and the comparison."""
    units = _units(unit, runs.per_split, runs.test_runs)
    test_mean, test_std = aggregate_over_seeds(units)
    baselines = {b: {"val_accuracy": float(np.mean(measured["val_accuracy"])),
                     **_summary_of(_units(unit, measured["test_per_split"], measured["test"]))}
                 for b, measured in runs.baselines.items()}  # fmt: skip
    chosen = max(BASELINE_NAMES, key=lambda b: baselines[b]["val_accuracy"])  # ties: majority
    chance_units = baselines[chosen]["test_per_split"]
    val_scores = [record["score"] for record in runs.val_records]
    val_mcc = [record["mcc"] for record in runs.val_records]
    num_splits = len(runs.split_records)
    simple: dict[str, Any] = {}
    for baseline, base_params in plan.simple_params.items():
        same = plan.simple_same[baseline]
        measured = None if same else runs.simple[baseline]
        scores = val_scores if same else measured["val_score"]
        simple[baseline] = {
            "params": base_params, "same_as_model": same, "val_score": float(np.mean(scores)),
            "val_per_unit": _val_units(unit, scores, num_splits),
            "val_mcc": float(np.mean(val_mcc if same else measured["val_mcc"])),
            **_summary_of(units if same else _units(unit, measured["test_per_split"], measured["test"])),
            # splits whose baseline numbers another run measured (simple_baseline_cache): the same numbers
            **({} if same else {"splits_from_cache": measured["from_cache"]}),
        }
    comparison = comparison_block(plan.name, plan.metric, unit, units, float(np.mean(val_scores)), simple, chosen,
                                  chance_units)  # fmt: skip
    test_clips = [r["sizes"]["test"] for r in runs.split_records]
    comparison.update(split_seeds=[r["seed"] for r in runs.split_records], test_clips=test_clips,
                      model_seeds=plan.seeds)  # fmt: skip
    comparison["cautions"] = cautions(plan.name, plan.seeds, runs.uses_seed, test_clips)
    for caution in comparison["cautions"]:
        log.warning("%s", caution)
    return {
        "unit": unit, "units": units, "test": test_mean, "test_std": test_std,
        "test_interval": {key: mean_interval([u[key] for u in units]) for key in KEY_METRICS},
        "baselines": baselines, "chosen": chosen,
        "paired": {key: paired_comparison([u[key] for u in units], [u[key] for u in chance_units]) for key in KEY_METRICS},
        "below": {key: bool(test_mean[key] < baselines[chosen]["test"][key]) for key in KEY_METRICS},
        "val_scores": val_scores, "val_mcc": val_mcc, "objective": float(np.mean(val_scores)),
        "simple": simple, "comparison": comparison,
        "total_matrix": np.sum([m["confusion_matrix"] for m in runs.test_runs], axis=0),
    }


def _write_outputs(plan: _Plan, runs: _Runs, prop: str, label_names: list[str], total_matrix: np.ndarray) -> None:
    _write_per_class(plan.out_dir / PER_CLASS_FILE, runs.test_runs)
    _write_predictions(plan.out_dir / PREDICTIONS_FILE, runs.prediction_rows)
    _plots(plan.out_dir, plan.name, prop, label_names, total_matrix, len(runs.test_runs), runs.histories,
           runs.learning_curve, plan.metric)  # fmt: skip


def _result_record(plan: _Plan, options: SplitOptions, dataset: RecognitionDataset, views, runs: _Runs,
                   summary: Mapping[str, Any], device_record: Mapping[str, Any], elapsed: float) -> dict[str, Any]:  # fmt: skip
    """metrics.json: the keys :func:`run_recognition` documents."""
    chosen, baselines = summary["chosen"], summary["baselines"]
    return {
        "property": dataset.property,
        "classifier": plan.name,
        "params": plan.params,
        "trainer": plan.config.to_dict(),
        "split_options": dict(options.__dict__),
        "seeds": plan.seeds,
        "validation": "cv5" if runs.is_cv else "holdout",
        "num_folds": len(validation_folds(views[0][1])),
        "split_sizes": runs.split_records[0]["sizes"],
        "splits": runs.split_records,
        "statistics_unit": summary["unit"],
        "label_names": list(views[0][1].label_names),
        "layout": {"name": dataset.layout.name, "nodes": list(dataset.layout.names), "channels": list(dataset.channels)},
        "num_parameters": runs.num_parameters,
        "device": dict(device_record),
        "objective": {"name": f"val_{plan.metric}", "value": summary["objective"]},
        "val_mcc": float(np.mean(summary["val_mcc"])),
        "val_mcc_std": _std(summary["val_mcc"]),
        "val": runs.val_records,
        "test": summary["test"],
        "test_std": summary["test_std"],
        "test_interval": summary["test_interval"],
        "test_per_split": runs.per_split,
        "test_per_seed": runs.test_runs,
        "test_confusion_matrix_total": summary["total_matrix"].astype(int).tolist(),
        "baseline": {**baselines[chosen], "name": chosen, "selected_by": "validation accuracy",
                     "val_accuracy": {b: baselines[b]["val_accuracy"] for b in BASELINE_NAMES}},  # fmt: skip
        "baselines": baselines,
        "paired_vs_baseline": summary["paired"],
        "below_baseline": summary["below"],
        "simple_baselines": summary["simple"],
        "comparison": summary["comparison"],
        "seed_changes_result": runs.uses_seed,
        "history": runs.histories,
        "final_history": runs.final_histories,
        "learning_curve": runs.learning_curve,
        "files": {
            "per_class": PER_CLASS_FILE, "predictions": PREDICTIONS_FILE, "confusion_matrix": CONFUSION_FILE,
            "learning_curves": CURVES_FILE, "checkpoint": runs.checkpoint_name,
        },
        "time_s": elapsed,
    }


def simple_baseline_params(value: str | Sequence[str] | None,
                           overrides: Mapping[str, Mapping[str, Any]] | None = None) -> dict[str, dict[str, Any]]:
    """``simple_baseline`` (a classifier name, a list of names, or None) -> {name: its params}: the
    registered defaults (which equal ``conf/classifier/<name>.yaml``) updated by ``overrides[name]``
    (``simple_baseline_params``, e.g. a smaller forest). A chance baseline, an unknown name, an
    override for a baseline not run or an unknown parameter is a :class:`~aslexp.errors.ConfigError`
    (bad input, exit 2)."""
    overrides = dict(overrides or {})
    if value is None or value == "" or (isinstance(value, str) and value.lower() in ("null", "none")):
        names: list[str] = []
    else:
        names = [str(v) for v in ([value] if isinstance(value, str) else list(value))]
    stray = sorted(set(overrides) - set(names))
    if stray:
        raise ConfigError(f"simple_baseline_params.{stray[0]}: {stray[0]} is not a simple baseline of this run "
                          f"(simple_baseline={names or None})")
    out: dict[str, dict[str, Any]] = {}
    for baseline in names:
        if baseline in BASELINE_NAMES:
            raise ConfigError(f"simple_baseline={baseline}: the chance baselines ({', '.join(BASELINE_NAMES)}) run in "
                             "every run already; name a model (rf, hgb, logreg, svm) or null")  # fmt: skip
        try:
            out[baseline] = resolve_params(baseline, dict(overrides.get(baseline) or {}) or None)
        except ValueError as error:
            key = f"simple_baseline_params.{baseline}" if overrides.get(baseline) else f"simple_baseline={baseline}"
            raise ConfigError(f"{key}: {error}") from None
    return out


def _simple_baseline_runs(view: RecognitionDataset, name: str, params: Mapping[str, Any], folds, train_val: ArraySplit,
                          test: ArraySplit, config: TrainerConfig, seeds: Sequence[int]) -> tuple[list[dict], list[dict]]:  # fmt: skip
    """A simple baseline run as the model is on one split: per seed, validated on every fold (its
    validation score the mean over folds, its budget the model's rule), retrained on train+val
    (``final_retrain``) and tested once. Returns (validation records, test metrics) per seed."""
    val_records, tests = [], []
    for seed in seeds:
        results, last = [], None
        for train_idx, val_idx in folds:
            seed_everything(seed, config.deterministic)
            last = _build(view, name, params)
            results.append(fit(last, ArraySplit.from_dataset(view, train_idx), ArraySplit.from_dataset(view, val_idx),
                               config, seed=seed))  # fmt: skip
        epochs, _ = _retrain_budget(results, config)
        val_records.append({"score": float(np.mean([r.best_val_score for r in results])),
                            "mcc": float(np.mean([r.best_val_mcc for r in results]))})  # fmt: skip
        if config.final_retrain or len(folds) > 1:
            seed_everything(seed, config.deterministic)
            y_pred = fit_final(_build(view, name, params), train_val, test, config, epochs=epochs, seed=seed).y_pred
        else:
            y_pred = last.predict(test.X, test.mask)
        tests.append(classification_metrics(test.y, y_pred, view.label_names))
    return val_records, tests


def _plots(out_dir: Path, name: str, prop: str, label_names: list[str], matrix: np.ndarray, runs: int,
           histories: dict, learning_curve: list, metric: str) -> None:  # fmt: skip
    """The run's two plots; skipped with a warning where matplotlib is not installed (a bare GPU
    node): every number they show is in metrics.json."""
    try:
        from aslexp.viz.plots import plot_confusion_matrix, plot_learning_curves
    except ImportError as error:
        log.warning("no plots (%s); the numbers are in metrics.json", error)
        return
    plot_confusion_matrix(matrix, label_names, out_dir / CONFUSION_FILE,
                          title=f"{name} on {prop}: test, {runs} run(s) summed")  # fmt: skip
    plot_learning_curves(histories, out_dir / CURVES_FILE, title=f"{name} on {prop} (validation runs)",
                         data_curve=learning_curve, metric=metric)  # fmt: skip


def plots_from_metrics(metrics: Mapping[str, Any], out_dir: str | Path) -> Path:
    """A run's two plots drawn again from its metrics.json alone, into ``out_dir`` (a run folder
    from a node without matplotlib has none; the run folder itself is never rewritten)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    _plots(out_dir, str(metrics["classifier"]), str(metrics["property"]), list(metrics["label_names"]),
           np.asarray(metrics["test_confusion_matrix_total"]), len(metrics["test_per_seed"]), metrics.get("history", {}),
           metrics.get("learning_curve", []), str(metrics["trainer"]["selection_metric"]))  # fmt: skip
    return out_dir


def _std(values: Sequence[float]) -> float:
    return float(np.std(values, ddof=1)) if len(values) > 1 else 0.0


PER_CLASS_COLUMNS = ["split", "seed", "label", "support", "predicted", "correct", "thesis_a", "precision", "recall", "f1"]


def _write_per_class(path: Path, test_runs: Sequence[Mapping[str, Any]]) -> None:
    """Per-class test metrics per run (split, seed), then their mean over runs (seed = 'mean').
    ``thesis_a`` is the thesis' per-class A = TP_c / N_test (Table 4.4); ``recall`` = TP_c / n_c."""
    rows = [{"split": m["split"], "seed": m["seed"], **row} for m in test_runs for row in m["per_class"]]
    labels = [row["label"] for row in test_runs[0]["per_class"]]
    for index, label in enumerate(labels):
        per_run = [m["per_class"][index] for m in test_runs]
        mean_row: dict[str, Any] = {"split": "all", "seed": "mean", "label": label}
        for key in PER_CLASS_COLUMNS[3:]:
            values = [row[key] for row in per_run if not (isinstance(row[key], float) and math.isnan(row[key]))]
            mean_row[key] = float(np.mean(values)) if values else math.nan
        rows.append(mean_row)
    with path.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=PER_CLASS_COLUMNS)
        writer.writeheader()
        writer.writerows(rows)


def _write_predictions(path: Path, rows: Sequence[Mapping[str, Any]]) -> None:
    with path.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=["video_id", "true", "predicted", "split", "seed", "correct"])
        writer.writeheader()
        writer.writerows(rows)
