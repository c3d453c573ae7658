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
from aslexp.data.splits import SplitOptions, resplit
from aslexp.errors import ConfigError
from aslexp.recognition import baseline_cache
from aslexp.recognition.device import check_precision, device_info, resolve_device
from aslexp.recognition.metrics import (
    aggregate_over_seeds,
    classification_metrics,
    mean_interval,
    paired_comparison,
    scalar_metrics,
)
from aslexp.recognition.models import BASELINE_NAMES, TorchClassifier, build_classifier, resolve_params
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
    without it the dataset's own split is the one split. Writes per_class.csv, predictions.csv,
    confusion_matrix.png, learning_curves.png and model.pt / model.joblib (the first run's final
    model) into ``out_dir``, and returns a JSON-ready dict (the job writes it as metrics.json):

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
    simple_baselines       per ``simple_baseline`` name (none: {}): params, val_score, val_mcc, test,
                           test_std, test_interval, test_per_split, same_as_model (the model itself:
                           its own numbers, not run again)
    comparison             model, strongest simple baseline (by validation score) and chance
                           baseline side by side (:func:`comparison_block`), the paired differences
                           and one sentence; what the job prints at its end
    splits                 per split: index, seed, sizes; statistics_unit: 'split' | 'seed'
    history, final_history per-epoch records of the validation and final runs, by 'seed S'
                           (one split) or 'split K seed S'
    learning_curve         scikit-learn models: score against training-set size (first run)
    device                 where torch models trained (type, name, precision)
    property, classifier, params, trainer, seeds, validation ('holdout'|'cv5'), num_folds,
    split_sizes, label_names, num_parameters, test_confusion_matrix_total, files, time_s
    """
    if "name" not in classifier:
        raise ValueError(f"classifier config needs a 'name' (got keys {sorted(classifier)})")
    name = str(classifier["name"])
    params = resolve_params(name, classifier.get("params"), classifier.get("module"))  # a module registers it
    config = TrainerConfig.parse(trainer)
    options = split if isinstance(split, SplitOptions) else SplitOptions.parse(split)
    seeds = [int(seed) for seed in seeds]
    if not seeds:
        raise ValueError("run_recognition needs at least one seed")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    if dataset.num_classes < 2:
        raise ValueError(f"dataset '{dataset.property}' has {dataset.num_classes} class(es); need >= 2")
    device = resolve_device(config.device)
    device_record = device_info(device, check_precision(config.precision, device))
    metric = config.selection_metric

    simple_params = simple_baseline_params(simple_baseline, simple_baseline_overrides)
    simple_same = {b: b == name and p == params for b, p in simple_params.items()}  # the model itself: not run twice

    views = split_views(dataset, options)
    label_names = list(views[0][1].label_names)
    start = time.perf_counter()
    val_records: list[dict[str, Any]] = []
    histories: dict[str, list[dict[str, float]]] = {}
    final_histories: dict[str, list[dict[str, float]]] = {}
    test_runs: list[dict[str, Any]] = []
    per_split: list[dict[str, float]] = []
    split_records: list[dict[str, Any]] = []
    baseline_runs: dict[str, dict[str, list]] = {n: {"val_accuracy": [], "test": [], "test_per_split": []} for n in BASELINE_NAMES}
    simple_runs: dict[str, dict[str, list]] = {b: {"val_score": [], "val_mcc": [], "test": [], "test_per_split": []}
                                               for b, same in simple_same.items() if not same}  # fmt: skip
    prediction_rows: list[dict[str, Any]] = []
    checkpoint_name, num_parameters, learning_curve = None, None, []
    is_cv = False
    total_runs = len(views) * len(seeds)
    for split_index, (split_seed, view) in enumerate(views):
        folds = validation_folds(view)
        is_cv = "folds" in view.splits
        train_val = ArraySplit.from_dataset(view, view.splits["train+val"])
        test_idx = np.asarray(view.splits["test"], dtype=np.int64)
        test = ArraySplit.from_dataset(view, test_idx)
        if len(test) == 0:
            raise ValueError(f"dataset '{view.property}': the 'test' split of split seed {split_seed} is empty")
        sizes = {"train": int(len(folds[0][0])), "val": int(len(folds[0][1])), "train+val": len(train_val), "test": len(test)}
        split_records.append({"index": split_index, "seed": split_seed, "sizes": sizes, "clips": len(view.y)})
        log.info(
            "recognition '%s' on %s, split %d/%d (seed %d): %d classes, X %s, train+val %d, test %d, %s, seeds %s",
            name, view.property, split_index + 1, len(views), split_seed, view.num_classes, tuple(view.X.shape),
            len(train_val), len(test), f"{len(folds)}-fold cv" if is_cv else f"hold-out (train {sizes['train']}, val {sizes['val']})",
            seeds,
        )
        split_tests = []
        for seed_index, seed in enumerate(seeds):
            run_key = f"seed {seed}" if len(views) == 1 else f"split {split_index} seed {seed}"
            fold_results = []
            last_model = None
            for fold_index, (train_idx, val_idx) in enumerate(folds):
                seed_everything(seed, config.deterministic)  # the same initial weights on every fold
                model = _build(view, name, params)
                first = split_index == 0 and seed_index == 0 and fold_index == 0
                result = fit(
                    model, ArraySplit.from_dataset(view, train_idx), ArraySplit.from_dataset(view, val_idx),
                    config, seed=seed, on_epoch_end=on_epoch_end if first else None, learning_curve=first,
                    on_epoch_record=on_epoch_record if first else None,
                )
                fold_results.append(result)
                last_model = model
                if first:
                    learning_curve = result.curve
                if fold_index == 0:
                    histories[run_key] = result.history
            epochs, fold_epochs = _retrain_budget(fold_results, config)
            val_records.append(
                {
                    "split": split_index, "seed": seed, "metric": metric,
                    "score": float(np.mean([r.best_val_score for r in fold_results])),
                    "mcc": float(np.mean([r.best_val_mcc for r in fold_results])),
                    "accuracy": float(np.mean([r.history[r.best_epoch - 1]["val_accuracy"] for r in fold_results])),
                    "best_epoch": epochs,
                    "fold_best_epochs": [r.best_epoch for r in fold_results],
                    "fold_budget_epochs": fold_epochs,
                    "fold_score": [r.best_val_score for r in fold_results],
                    "fold_mcc": [r.best_val_mcc for r in fold_results],
                    "epochs_run": [r.epochs_run for r in fold_results],
                    "stopped_early": [r.stopped_early for r in fold_results],
                }
            )

            if config.final_retrain or last_model is None:
                seed_everything(seed, config.deterministic)  # same initial weights as the validation run
                final_model = _build(view, name, params)
                final = fit_final(final_model, train_val, test, config, epochs=epochs, seed=seed)
                y_pred = final.y_pred
                final_histories[run_key] = final.fit.history
            else:
                if is_cv:
                    raise ValueError("trainer.final_retrain=false needs a hold-out split (cv5 has no single model to test)")
                final_model = last_model
                y_pred = final_model.predict(test.X, test.mask)
            metrics = classification_metrics(test.y, y_pred, view.label_names)
            metrics.update(split=split_index, seed=seed)
            test_runs.append(metrics)
            split_tests.append(metrics)
            log.info(
                "run %d/%d (split %d, seed %d): val %s %.3f (epochs %d) -> test acc %.3f, balanced %.3f, MCC %.3f  [%.0fs]",
                len(test_runs), total_runs, split_index, seed, metric, val_records[-1]["score"], epochs,
                metrics["accuracy"], metrics["balanced_accuracy"], metrics["mcc"], time.perf_counter() - start,
            )
            for row_index, predicted in zip(test_idx, y_pred):
                true = int(view.y[row_index])
                prediction_rows.append(
                    {
                        "video_id": view.video_ids[row_index], "true": view.label_names[true],
                        "predicted": view.label_names[int(predicted)], "split": split_index, "seed": seed,
                        "correct": int(true == int(predicted)),
                    }
                )
            if checkpoint_name is None:
                checkpoint_name = "model" + final_model.checkpoint_suffix
                save_checkpoint(
                    final_model, out_dir / checkpoint_name,
                    extra={"seed": seed, "split": split_index, "split_seed": split_seed, "epochs": epochs,
                           "label_names": list(view.label_names), "property": view.property},  # fmt: skip
                )
                if isinstance(final_model, TorchClassifier):
                    num_parameters = final_model.num_parameters()
        per_split.append(aggregate_over_seeds(split_tests)[0])
        for baseline, runs in _baseline_runs(view, folds, train_val, test, config, seeds).items():
            baseline_runs[baseline]["val_accuracy"] += runs["val_accuracy"]
            baseline_runs[baseline]["test"] += runs["test"]
            baseline_runs[baseline]["test_per_split"].append(aggregate_over_seeds(runs["test"])[0])
        data = baseline_cache.data_digest(
            [view.X, view.mask, view.y, train_val.X, train_val.mask, train_val.y, test.X, test.mask, test.y,
             *(np.asarray(i) for fold in folds for i in fold)]) if simple_runs and simple_baseline_cache else ""
        for baseline, runs in simple_runs.items():
            key = baseline_cache.cache_key(baseline, simple_params[baseline], config, seeds, view.label_names, data)
            val, tests, reused = baseline_cache.cached(
                simple_baseline_cache, key, baseline,
                lambda: _simple_baseline_runs(view, baseline, simple_params[baseline], folds, train_val, test, config,
                                              seeds))  # fmt: skip
            runs["from_cache"] = runs.get("from_cache", 0) + int(reused)
            runs["val_score"] += [v["score"] for v in val]
            runs["val_mcc"] += [v["mcc"] for v in val]
            runs["test"] += tests
            runs["test_per_split"].append(aggregate_over_seeds(tests)[0])
            log.info("simple baseline %s (split %d): val %s %.3f -> test MCC %.3f, balanced %.3f%s", baseline,
                     split_index, metric, float(np.mean([v["score"] for v in val])), runs["test_per_split"][-1]["mcc"],
                     runs["test_per_split"][-1]["balanced_accuracy"],
                     " (measured by an earlier run: simple_baseline_cache)" if reused else "")  # fmt: skip

    unit = "split" if len(views) > 1 else "seed"
    units = per_split if unit == "split" else [scalar_metrics(m) for m in test_runs]
    test_mean, test_std = aggregate_over_seeds(units)
    test_interval = {key: mean_interval([u[key] for u in units]) for key in KEY_METRICS}

    baselines: dict[str, Any] = {}
    for baseline, runs in baseline_runs.items():
        base_units = runs["test_per_split"] if unit == "split" else [scalar_metrics(m) for m in runs["test"]]
        mean, std = aggregate_over_seeds(base_units)
        baselines[baseline] = {
            "val_accuracy": float(np.mean(runs["val_accuracy"])), "test": mean, "test_std": std,
            "test_interval": {key: mean_interval([u[key] for u in base_units]) for key in KEY_METRICS},
            "test_per_split": base_units,
        }
    chosen = max(BASELINE_NAMES, key=lambda b: baselines[b]["val_accuracy"])  # ties: majority
    paired = {key: paired_comparison([u[key] for u in units], [u[key] for u in baselines[chosen]["test_per_split"]])
              for key in KEY_METRICS}  # fmt: skip
    below = {key: bool(test_mean[key] < baselines[chosen]["test"][key]) for key in KEY_METRICS}

    val_scores = [record["score"] for record in val_records]
    val_mcc = [record["mcc"] for record in val_records]
    simple: dict[str, Any] = {}
    for baseline, base_params in simple_params.items():
        if simple_same[baseline]:
            base_units, scores, mccs = units, val_scores, val_mcc
        else:
            runs = simple_runs[baseline]
            base_units = runs["test_per_split"] if unit == "split" else [scalar_metrics(m) for m in runs["test"]]
            scores, mccs = runs["val_score"], runs["val_mcc"]
        mean, std = aggregate_over_seeds(base_units)
        simple[baseline] = {
            "params": base_params, "same_as_model": simple_same[baseline], "val_score": float(np.mean(scores)),
            "val_mcc": float(np.mean(mccs)), "test": mean, "test_std": std,
            "test_interval": {key: mean_interval([u[key] for u in base_units]) for key in KEY_METRICS},
            "test_per_split": base_units,
            # splits whose baseline numbers another run measured (simple_baseline_cache): the same numbers
            **({} if simple_same[baseline] else {"splits_from_cache": simple_runs[baseline].get("from_cache", 0)}),
        }
    comparison = comparison_block(
        name, metric, unit, units, float(np.mean(val_scores)), simple, chosen, baselines[chosen]["test_per_split"],
    )
    comparison.update(split_seeds=[r["seed"] for r in split_records], test_clips=[r["sizes"]["test"] for r in split_records],
                      model_seeds=seeds)  # fmt: skip
    total_matrix = np.sum([m["confusion_matrix"] for m in test_runs], axis=0)

    _write_per_class(out_dir / PER_CLASS_FILE, test_runs)
    _write_predictions(out_dir / PREDICTIONS_FILE, prediction_rows)
    _plots(out_dir, name, dataset.property, label_names, total_matrix, len(test_runs), histories, learning_curve, metric)

    elapsed = time.perf_counter() - start
    log.info(
        "%s on %s: val %s %.3f +- %.3f, test MCC %.3f +- %.3f over %d %s(s) (baseline %s %.3f), %.1fs",
        name, dataset.property, metric, float(np.mean(val_scores)), _std(val_scores), test_mean["mcc"],
        test_std["mcc"], len(units), unit, chosen, baselines[chosen]["test"]["mcc"], elapsed,
    )
    first_sizes = split_records[0]["sizes"]
    return {
        "property": dataset.property,
        "classifier": name,
        "params": params,
        "trainer": config.to_dict(),
        "split_options": dict(options.__dict__),
        "seeds": seeds,
        "validation": "cv5" if is_cv else "holdout",
        "num_folds": len(validation_folds(views[0][1])),
        "split_sizes": first_sizes,
        "splits": split_records,
        "statistics_unit": unit,
        "label_names": label_names,
        "layout": {"name": dataset.layout.name, "nodes": list(dataset.layout.names), "channels": list(dataset.channels)},
        "num_parameters": num_parameters,
        "device": device_record,
        "objective": {"name": f"val_{metric}", "value": float(np.mean(val_scores))},
        "val_mcc": float(np.mean(val_mcc)),
        "val_mcc_std": _std(val_mcc),
        "val": val_records,
        "test": test_mean,
        "test_std": test_std,
        "test_interval": test_interval,
        "test_per_split": per_split,
        "test_per_seed": test_runs,
        "test_confusion_matrix_total": total_matrix.astype(int).tolist(),
        "baseline": {**baselines[chosen], "name": chosen, "selected_by": "validation accuracy",
                     "val_accuracy": {b: baselines[b]["val_accuracy"] for b in BASELINE_NAMES}},  # fmt: skip
        "baselines": baselines,
        "paired_vs_baseline": paired,
        "below_baseline": below,
        "simple_baselines": simple,
        "comparison": comparison,
        "history": histories,
        "final_history": final_histories,
        "learning_curve": learning_curve,
        "files": {
            "per_class": PER_CLASS_FILE, "predictions": PREDICTIONS_FILE, "confusion_matrix": CONFUSION_FILE,
            "learning_curves": CURVES_FILE, "checkpoint": checkpoint_name,
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


COMPARED = ("mcc", "balanced_accuracy")  # the comparison's columns
CHANCE_WORDS = {"majority": "majority class", "stratified": "stratified chance baseline"}


def comparison_block(name: str, metric: str, unit: str, units: Sequence[Mapping[str, float]], val_score: float,
                     simple: Mapping[str, Mapping[str, Any]], chance: str,
                     chance_units: Sequence[Mapping[str, float]]) -> dict[str, Any]:  # fmt: skip
    """The model beside the simple baselines ``simple`` and the chance baseline ``chance`` on the same
    units (splits, or seeds of one split): test MCC and balanced accuracy (mean, std, n) per row, the
    paired differences model minus the reference (the simple baseline with the best validation
    score, never chosen by test) and model minus chance, a verdict on test MCC and one sentence
    saying what the model adds. Rows: the model, each simple baseline that is not the model itself
    (the reference first, ``reference: true``), the chance baseline."""

    def row(role: str, row_name: str, per_unit: Sequence[Mapping[str, float]], **extra) -> dict[str, Any]:
        test = {key: {k: v for k, v in mean_interval([u[key] for u in per_unit]).items() if k in ("mean", "std", "n")}
                for key in COMPARED}  # fmt: skip
        return {"role": role, "name": row_name, **extra, "test": test}

    def paired(per_unit: Sequence[Mapping[str, float]]) -> dict[str, Any]:
        return {key: paired_comparison([u[key] for u in units], [u[key] for u in per_unit]) for key in COMPARED}

    order = sorted(simple, key=lambda b: -simple[b]["val_score"])  # stable: ties keep the order listed
    reference = order[0] if order else None
    selected_by = f"validation {metric}" if len(simple) > 1 else "the only one"
    model_is_reference = reference is not None and bool(simple[reference]["same_as_model"])
    rows = [row("model", name, units, val_score=val_score, reference=model_is_reference)]
    for baseline in order:
        if not simple[baseline]["same_as_model"]:
            rows.append(row("simple_baseline", baseline, simple[baseline]["test_per_split"],
                            val_score=simple[baseline]["val_score"], reference=baseline == reference,
                            selected_by=selected_by))  # fmt: skip
    rows.append(row("chance_baseline", chance, chance_units, selected_by="validation accuracy"))
    vs_simple = paired(simple[reference]["test_per_split"]) if reference is not None else None
    vs_chance = paired(chance_units)
    if reference is None:
        verdict = "no_simple_baseline"
    elif model_is_reference:
        verdict = "model_is_simple_baseline"
    else:
        difference = vs_simple["mcc"]["diff"]["mean"]
        verdict = "above" if difference > 0 else "below" if difference < 0 else "equal"
    block = {"metrics": list(COMPARED), "unit": unit, "n": len(units), "candidates": list(simple),
             "simple_baseline": reference, "simple_baseline_selected_by": selected_by, "chance_baseline": chance,
             "rows": rows, "model_minus_simple_baseline": vs_simple, "model_minus_chance_baseline": vs_chance,
             "verdict": verdict}  # fmt: skip
    block["sentence"] = _comparison_sentence(name, block)
    return block


def _signed(value: float) -> str:
    return f"{value:+.3f}"


def _comparison_sentence(name: str, block: Mapping[str, Any]) -> str:
    vs_chance, vs_simple = block["model_minus_chance_baseline"], block["model_minus_simple_baseline"]
    reference, verdict = block["simple_baseline"], block["verdict"]
    chance = CHANCE_WORDS.get(block["chance_baseline"], f"chance baseline {block['chance_baseline']}")

    def gains(paired: Mapping[str, Any]) -> str:
        return (f"{_signed(paired['mcc']['diff']['mean'])} test MCC and "
                f"{_signed(paired['balanced_accuracy']['diff']['mean'])} balanced accuracy")

    def interval(paired: Mapping[str, Any]) -> str:
        diff = paired["mcc"]["diff"]
        if block["unit"] != "split":
            return " on one split (split.repeats=10 gives an interval over splits)"
        state = {1: "resolved above 0", -1: "resolved below 0", 0: "not resolved: it includes 0"}[paired["mcc"]["resolved"]]
        return f" (MCC 95% interval [{diff['low']:+.3f}, {diff['high']:+.3f}] over {diff['n']} paired splits, {state})"

    if verdict == "no_simple_baseline":
        return f"{name} adds {gains(vs_chance)} over the {chance} (no simple baseline: simple_baseline=null)."
    if verdict == "model_is_simple_baseline":
        best = (f"the strongest simple baseline itself (the best of {'/'.join(block['candidates'])} by validation)"
                if len(block["candidates"]) > 1 else "the simple baseline itself")  # fmt: skip
        return (f"{name} is {best}; it adds {gains(vs_chance)} over the {chance}; "
                f"classifier=stgcn (or another model) is compared with it.")  # fmt: skip
    if reference == name:
        reference = f"{reference} at its defaults"
    strongest = (f"{reference} (the strongest simple baseline by validation)" if len(block["candidates"]) > 1
                 else f"the simple baseline {reference}")  # fmt: skip
    if verdict == "below":
        text = f"{name} is below {strongest}: {gains(vs_simple)}{interval(vs_simple)}"
    else:
        text = f"{name} adds {gains(vs_simple)} over {strongest}{interval(vs_simple)}"
    if vs_chance["mcc"]["diff"]["mean"] <= 0:
        text += f"; it is not above the {chance}"
    return text + "."


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
