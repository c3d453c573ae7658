"""One recognition experiment: a classifier on a dataset, several seeds, one test each.

For every seed:
  1. validation: train on 'train' with early stopping on 'val' MCC (cv5: on each of the 5 folds
     of 'train+val'; the seed's val MCC is the mean over folds, its epoch count the median of
     the folds' best epochs);
  2. final: retrain a fresh model on 'train+val' for that epoch count and test once on 'test'.
Then: mean and std over seeds of every scalar test metric, the chance baselines on the same
split, and the run-folder artefacts (per_class.csv, predictions.csv, plots, checkpoint).

The objective a sweep maximises is ``result["val_mcc"]`` (mean over seeds); ``on_epoch_end``
receives the first seed's (first fold's) epochs, for pruning.
"""

from __future__ import annotations

import csv
import logging
import math
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from aslexp.data.dataset import RecognitionDataset
from aslexp.recognition.metrics import aggregate_over_seeds, classification_metrics
from aslexp.recognition.models import BASELINE_NAMES, TorchClassifier, build_classifier, resolve_params
from aslexp.recognition.train import (
    ArraySplit,
    EpochCallback,
    TrainerConfig,
    fit,
    fit_final,
    save_checkpoint,
    seed_everything,
)
from aslexp.viz.plots import plot_confusion_matrix, plot_learning_curves

log = logging.getLogger(__name__)

PER_CLASS_FILE = "per_class.csv"
PREDICTIONS_FILE = "predictions.csv"
CONFUSION_FILE = "confusion_matrix.png"
CURVES_FILE = "learning_curves.png"


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


def _build(dataset: RecognitionDataset, name: str, params: Mapping[str, Any]):
    _, channels, frames, nodes, _ = dataset.X.shape
    return build_classifier(name, dict(params), channels, frames, nodes, dataset.num_classes, dataset.layout)


def _test_baselines(
    dataset: RecognitionDataset, train_val: ArraySplit, test: ArraySplit, config: TrainerConfig, seeds: Sequence[int]
) -> dict[str, Any]:
    """Majority and stratified baselines fitted on 'train+val', tested on 'test'; 'best' is the
    one with the higher mean test accuracy (the stronger chance reference)."""
    results: dict[str, Any] = {}
    for name in BASELINE_NAMES:
        per_seed = []
        for seed in seeds:
            final = fit_final(_build(dataset, name, {}), train_val, test, config, epochs=1, seed=seed)
            per_seed.append(classification_metrics(test.y, final.y_pred, dataset.label_names))
        mean, std = aggregate_over_seeds(per_seed)
        results[name] = {"test": mean, "test_std": std}
    best = max(BASELINE_NAMES, key=lambda name: results[name]["test"]["accuracy"])
    return {"name": best, **results[best], "all": results}


def run_recognition(
    dataset: RecognitionDataset,
    classifier: Mapping[str, Any],
    trainer: Mapping[str, Any] | None,
    seeds: Sequence[int],
    out_dir: str | Path,
    on_epoch_end: EpochCallback | None = None,
) -> dict[str, Any]:
    """Validate, retrain and test ``classifier`` = {"name": ..., "params": {...}} on ``dataset``.

    Writes per_class.csv, predictions.csv, confusion_matrix.png, learning_curves.png and
    model.pt / model.joblib (the first seed's final model) into ``out_dir``, and returns a
    JSON-ready dict (the job writes it as metrics.json) with keys:

    val_mcc, val_mcc_std   the objective: mean (std) over seeds of the best validation MCC
    val                    per seed: mcc, accuracy, best_epoch, fold_best_epochs, fold_mcc, ...
    test, test_std         mean / std over seeds of every scalar test metric (accuracy,
                           accuracy_ci_low/high, balanced_accuracy, precision/recall/f1 micro
                           and macro, mcc, n, cardinality_accuracy_r)
    test_per_seed          full :func:`classification_metrics` per seed (+ 'seed')
    baseline               the better of majority/stratified: name, test, test_std
    baselines              both baselines
    history, final_history per-epoch records of the validation and final runs, by 'seed S'
    property, classifier, params, trainer, seeds, validation ('holdout'|'cv5'), num_folds,
    split_sizes, label_names, num_parameters, test_confusion_matrix_total, files, time_s
    """
    if "name" not in classifier:
        raise ValueError(f"classifier config needs a 'name' (got keys {sorted(classifier)})")
    name = str(classifier["name"])
    params = resolve_params(name, classifier.get("params"))
    config = TrainerConfig.from_dict(trainer)
    seeds = [int(seed) for seed in seeds]
    if not seeds:
        raise ValueError("run_recognition needs at least one seed")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    if dataset.num_classes < 2:
        raise ValueError(f"dataset '{dataset.property}' has {dataset.num_classes} class(es); need >= 2")

    folds = validation_folds(dataset)
    is_cv = "folds" in dataset.splits
    train_val = ArraySplit.from_dataset(dataset, dataset.splits["train+val"])
    test_idx = np.asarray(dataset.splits["test"], dtype=np.int64)
    test = ArraySplit.from_dataset(dataset, test_idx)
    if len(test) == 0:
        raise ValueError(f"dataset '{dataset.property}': the 'test' split is empty")
    log.info(
        "recognition '%s' on %s: %d classes, X %s, train+val %d, test %d, %s, seeds %s",
        name, dataset.property, dataset.num_classes, tuple(dataset.X.shape), len(train_val), len(test),
        f"{len(folds)}-fold cv" if is_cv else f"hold-out (train {len(folds[0][0])}, val {len(folds[0][1])})", seeds,
    )

    start = time.perf_counter()
    val_records: list[dict[str, Any]] = []
    histories: dict[str, list[dict[str, float]]] = {}
    final_histories: dict[str, list[dict[str, float]]] = {}
    test_per_seed: list[dict[str, Any]] = []
    prediction_rows: list[dict[str, Any]] = []
    checkpoint_name = None
    num_parameters = None
    for seed_index, seed in enumerate(seeds):
        fold_results = []
        last_model = None
        for fold_index, (train_idx, val_idx) in enumerate(folds):
            seed_everything(seed, config.deterministic)  # the same initial weights on every fold
            model = _build(dataset, name, params)
            callback = on_epoch_end if seed_index == 0 and fold_index == 0 else None
            result = fit(
                model, ArraySplit.from_dataset(dataset, train_idx), ArraySplit.from_dataset(dataset, val_idx),
                config, seed=seed, on_epoch_end=callback,
            )
            fold_results.append(result)
            last_model = model
            if fold_index == 0:
                histories[f"seed {seed}"] = result.history
        best_epochs = [r.best_epoch for r in fold_results]
        epochs = max(1, int(round(float(np.median(best_epochs)))))
        val_records.append(
            {
                "seed": seed,
                "mcc": float(np.mean([r.best_val_mcc for r in fold_results])),
                "accuracy": float(np.mean([r.history[r.best_epoch - 1]["val_accuracy"] for r in fold_results])),
                "best_epoch": epochs,
                "fold_best_epochs": best_epochs,
                "fold_mcc": [r.best_val_mcc for r in fold_results],
                "epochs_run": [r.epochs_run for r in fold_results],
                "stopped_early": [r.stopped_early for r in fold_results],
            }
        )

        if config.final_retrain or last_model is None:
            seed_everything(seed, config.deterministic)  # same initial weights as the validation run
            final_model = _build(dataset, name, params)
            final = fit_final(final_model, train_val, test, config, epochs=epochs, seed=seed)
            y_pred = final.y_pred
            final_histories[f"seed {seed}"] = final.fit.history
        else:
            if is_cv:
                raise ValueError("trainer.final_retrain=false needs a hold-out split (cv5 has no single model to test)")
            final_model = last_model
            y_pred = final_model.predict(test.X, test.mask)
        metrics = classification_metrics(test.y, y_pred, dataset.label_names)
        metrics["seed"] = seed
        test_per_seed.append(metrics)
        log.info(
            "seed %d: val MCC %.3f (best epoch %d) -> test acc %.3f [%.3f, %.3f], balanced %.3f, MCC %.3f",
            seed, val_records[-1]["mcc"], epochs, metrics["accuracy"], metrics["accuracy_ci_low"],
            metrics["accuracy_ci_high"], metrics["balanced_accuracy"], metrics["mcc"],
        )
        for row_index, predicted in zip(test_idx, y_pred):
            true = int(dataset.y[row_index])
            prediction_rows.append(
                {
                    "video_id": dataset.video_ids[row_index], "true": dataset.label_names[true],
                    "predicted": dataset.label_names[int(predicted)], "seed": seed, "correct": int(true == int(predicted)),
                }
            )
        if seed_index == 0:
            checkpoint_name = "model" + final_model.checkpoint_suffix
            save_checkpoint(
                final_model, out_dir / checkpoint_name,
                extra={"seed": seed, "epochs": epochs, "label_names": list(dataset.label_names), "property": dataset.property},
            )
            if isinstance(final_model, TorchClassifier):
                num_parameters = final_model.num_parameters()

    test_mean, test_std = aggregate_over_seeds(test_per_seed)
    test_mean.pop("seed", None)
    test_std.pop("seed", None)
    baseline = _test_baselines(dataset, train_val, test, config, seeds)
    val_mcc = [record["mcc"] for record in val_records]
    total_matrix = np.sum([m["confusion_matrix"] for m in test_per_seed], axis=0)

    _write_per_class(out_dir / PER_CLASS_FILE, test_per_seed)
    _write_predictions(out_dir / PREDICTIONS_FILE, prediction_rows)
    plot_confusion_matrix(
        total_matrix, dataset.label_names, out_dir / CONFUSION_FILE,
        title=f"{name} on {dataset.property}: test, {len(seeds)} seed(s), row-normalised",
    )
    plot_learning_curves(histories, out_dir / CURVES_FILE, title=f"{name} on {dataset.property} (validation runs)")

    elapsed = time.perf_counter() - start
    log.info(
        "%s on %s: val MCC %.3f +- %.3f, test acc %.3f +- %.3f (baseline %s %.3f), %.1fs",
        name, dataset.property, float(np.mean(val_mcc)), _std(val_mcc), test_mean["accuracy"], test_std["accuracy"],
        baseline["name"], baseline["test"]["accuracy"], elapsed,
    )
    return {
        "property": dataset.property,
        "classifier": name,
        "params": params,
        "trainer": config.to_dict(),
        "seeds": seeds,
        "validation": "cv5" if is_cv else "holdout",
        "num_folds": len(folds),
        "split_sizes": {"train": int(len(folds[0][0])), "val": int(len(folds[0][1])), "train+val": len(train_val), "test": len(test)},
        "label_names": list(dataset.label_names),
        "num_parameters": num_parameters,
        "val_mcc": float(np.mean(val_mcc)),
        "val_mcc_std": _std(val_mcc),
        "val": val_records,
        "test": test_mean,
        "test_std": test_std,
        "test_per_seed": test_per_seed,
        "test_confusion_matrix_total": total_matrix.astype(int).tolist(),
        "baseline": {"name": baseline["name"], "test": baseline["test"], "test_std": baseline["test_std"]},
        "baselines": baseline["all"],
        "history": histories,
        "final_history": final_histories,
        "files": {
            "per_class": PER_CLASS_FILE, "predictions": PREDICTIONS_FILE, "confusion_matrix": CONFUSION_FILE,
            "learning_curves": CURVES_FILE, "checkpoint": checkpoint_name,
        },
        "time_s": elapsed,
    }


def _std(values: Sequence[float]) -> float:
    return float(np.std(values, ddof=1)) if len(values) > 1 else 0.0


def _write_per_class(path: Path, test_per_seed: Sequence[Mapping[str, Any]]) -> None:
    """Per-class test metrics per seed, then their mean over seeds (seed = 'mean')."""
    columns = ["seed", "label", "support", "predicted", "correct", "thesis_a", "precision", "recall", "f1"]
    rows = [{"seed": m["seed"], **row} for m in test_per_seed for row in m["per_class"]]
    labels = [row["label"] for row in test_per_seed[0]["per_class"]]
    for index, label in enumerate(labels):
        per_seed = [m["per_class"][index] for m in test_per_seed]
        mean_row: dict[str, Any] = {"seed": "mean", "label": label}
        for key in columns[2:]:
            values = [row[key] for row in per_seed if not (isinstance(row[key], float) and math.isnan(row[key]))]
            mean_row[key] = float(np.mean(values)) if values else math.nan
        rows.append(mean_row)
    with path.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=columns, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)


def _write_predictions(path: Path, rows: Sequence[Mapping[str, Any]]) -> None:
    with path.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=["video_id", "true", "predicted", "seed", "correct"])
        writer.writeheader()
        writer.writerows(rows)
