"""Classification metrics, per class and across models/properties; all results JSON-ready.

Every function returns plain Python floats, ints, lists and dicts (NaN where a value is
undefined, with a ``*_note`` saying why), so ``json.dumps`` takes them as they are.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from scipy import stats
from sklearn.metrics import (
    balanced_accuracy_score,
    confusion_matrix,
    matthews_corrcoef,
    precision_recall_fscore_support,
)

Z_95 = 1.959963984540054  # two-sided 95% normal quantile ("1.96")


def accuracy_ci(correct: int, n: int, z: float = Z_95) -> tuple[float, float, float]:
    """Accuracy p = correct/n with the normal-approximation interval p +- z*sqrt(p(1-p)/n),
    clipped to [0, 1]. Returns (p, low, high); NaNs when n == 0.
    """
    if n == 0:
        return math.nan, math.nan, math.nan
    p = correct / n
    half_width = z * math.sqrt(p * (1.0 - p) / n)
    return p, max(0.0, p - half_width), min(1.0, p + half_width)


def mcc(y_true: Sequence[int], y_pred: Sequence[int]) -> float:
    """Matthews correlation coefficient (multiclass, Gorodkin's R_K); 0 when undefined."""
    if len(y_true) == 0:
        return math.nan
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return float(matthews_corrcoef(y_true, y_pred))


def selection_score(y_true: Sequence[int], y_pred: Sequence[int], metric: str) -> float:
    """One validation score: mcc | accuracy | balanced_accuracy | f1_micro | f1_macro (macro over
    the classes present in y_true or y_pred; NaN on an empty set)."""
    y_true, y_pred = np.asarray(y_true), np.asarray(y_pred)
    if len(y_true) == 0:
        return math.nan
    if metric == "mcc":
        return mcc(y_true, y_pred)
    if metric == "accuracy":
        return float((y_true == y_pred).mean())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if metric == "balanced_accuracy":
            return float(balanced_accuracy_score(y_true, y_pred))
        if metric in ("f1_micro", "f1_macro"):
            return float(precision_recall_fscore_support(y_true, y_pred, average=metric[3:], zero_division=0)[2])
    raise ValueError(f"unknown selection metric {metric!r}; expected mcc, accuracy, balanced_accuracy, f1_micro or f1_macro")


def classification_metrics(y_true: Sequence[int], y_pred: Sequence[int], label_names: Sequence[str]) -> dict[str, Any]:
    """All single-model metrics of one prediction of a labelled set.

    Keys: ``n``, ``accuracy``, ``accuracy_ci_low``/``_high`` (95%, normal approximation),
    ``balanced_accuracy`` (mean recall over the classes present in y_true), ``precision_micro``,
    ``recall_micro``, ``f1_micro``, ``precision_macro``, ``recall_macro``, ``f1_macro``
    (macro = unweighted mean over the classes present in y_true or y_pred; 0 where a class was
    never predicted), ``mcc``, ``confusion_matrix`` (rows = true, columns = predicted, in
    ``label_names`` order), ``label_names``, ``per_class`` (see :func:`per_class_metrics`) and
    ``cardinality_accuracy`` (see :func:`cardinality_accuracy_correlation`).
    """
    y_true = np.asarray(y_true, dtype=np.int64)
    y_pred = np.asarray(y_pred, dtype=np.int64)
    if y_true.shape != y_pred.shape or y_true.ndim != 1:
        raise ValueError(f"y_true and y_pred must be 1-D of equal length, got {y_true.shape} and {y_pred.shape}")
    num_classes = len(label_names)
    for name, values in (("y_true", y_true), ("y_pred", y_pred)):
        if len(values) and (values.min() < 0 or values.max() >= num_classes):
            raise ValueError(f"{name} holds class ids outside 0..{num_classes - 1} ({num_classes} label_names)")
    n = len(y_true)
    correct = int((y_true == y_pred).sum())
    accuracy, ci_low, ci_high = accuracy_ci(correct, n)
    result: dict[str, Any] = {"n": n, "accuracy": accuracy, "accuracy_ci_low": ci_low, "accuracy_ci_high": ci_high}

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # undefined precision (class never predicted) -> 0, stated above
        result["balanced_accuracy"] = float(balanced_accuracy_score(y_true, y_pred)) if n else math.nan
        for average in ("micro", "macro"):
            precision, recall, f1, _ = precision_recall_fscore_support(y_true, y_pred, average=average, zero_division=0)
            result[f"precision_{average}"] = float(precision) if n else math.nan
            result[f"recall_{average}"] = float(recall) if n else math.nan
            result[f"f1_{average}"] = float(f1) if n else math.nan
    result["mcc"] = mcc(y_true, y_pred)
    matrix = confusion_matrix(y_true, y_pred, labels=np.arange(num_classes))
    result["confusion_matrix"] = matrix.astype(int).tolist()
    result["label_names"] = [str(name) for name in label_names]
    per_class = per_class_metrics(matrix, label_names)
    result["per_class"] = per_class
    result["cardinality_accuracy"] = cardinality_accuracy_correlation(
        [row["support"] for row in per_class], [row["recall"] for row in per_class]
    )
    # The thesis' Pearson r (section 4.4) is against its per-class "A" = TP_c / N_test.
    result["cardinality_thesis_a"] = cardinality_accuracy_correlation(
        [row["support"] for row in per_class], [row["thesis_a"] for row in per_class]
    )
    return result


def per_class_metrics(matrix: np.ndarray, label_names: Sequence[str]) -> list[dict[str, Any]]:
    """One dict per class from a confusion matrix (rows true, columns predicted).

    ``support`` = number of true items of the class (its cardinality in the evaluated set);
    ``recall`` = share of them classified correctly; ``thesis_a`` = TP_c / N, the share of the
    whole evaluated set that is of class c and classified correctly: the thesis' per-class "A" of
    Table 4.4 (THESIS.md 2.5), which sums over classes to the accuracy and is proportional to
    the cardinality; ``precision`` = share of the items predicted as the class that are of the
    class; ``f1`` = 2TP / (support + predicted); ``predicted`` = how often the class was predicted.
    NaN where the denominator is 0.
    """
    matrix = np.asarray(matrix)
    total = int(matrix.sum())
    rows = []
    for index, name in enumerate(label_names):
        true_positive = int(matrix[index, index])
        support = int(matrix[index].sum())
        predicted = int(matrix[:, index].sum())
        recall = true_positive / support if support else math.nan
        precision = true_positive / predicted if predicted else math.nan
        # 2TP / (2TP + FP + FN): defined (possibly 0) whenever the class occurs at all.
        f1 = 2 * true_positive / (support + predicted) if support + predicted else math.nan
        rows.append(
            {
                "label": str(name), "support": support, "predicted": predicted, "correct": true_positive,
                "thesis_a": true_positive / total if total else math.nan,
                "precision": precision, "recall": recall, "f1": f1,
            }
        )
    return rows


def cardinality_accuracy_correlation(support: Sequence[int], accuracy: Sequence[float]) -> dict[str, Any]:
    """Pearson r (and two-sided p-value) between the per-class cardinality and per-class accuracy.

    Only classes with support > 0 take part (others have no accuracy). Undefined (NaN, with a
    ``note``) with fewer than 3 such classes or when either variable is constant.
    """
    support = np.asarray(support, dtype=np.float64)
    accuracy = np.asarray(accuracy, dtype=np.float64)
    present = support > 0
    x, y = support[present], accuracy[present]
    result: dict[str, Any] = {"r": math.nan, "p_value": math.nan, "num_classes": int(present.sum()), "note": ""}
    if len(x) < 3:
        result["note"] = f"undefined: {len(x)} classes with test items (need >= 3)"
    elif np.ptp(x) == 0 or np.ptp(y) == 0:
        result["note"] = "undefined: " + ("cardinality" if np.ptp(x) == 0 else "accuracy") + " is the same for every class"
    else:
        r, p_value = stats.pearsonr(x, y)
        result["r"], result["p_value"] = float(r), float(p_value)
    return result


def scalar_metrics(metrics: Mapping[str, Any]) -> dict[str, float]:
    """The scalar (int/float) entries of a metrics dict, as floats."""
    return {
        key: float(value)
        for key, value in metrics.items()
        if isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
    }


# Per-run Wald bounds are intervals of one run's accuracy; averaging them over runs is not an
# interval of anything, so aggregation leaves them out (use :func:`mean_interval`).
PER_RUN_ONLY = frozenset({"accuracy_ci_low", "accuracy_ci_high", "seed", "split"})


def aggregate_over_seeds(per_seed: Sequence[Mapping[str, Any]]) -> tuple[dict[str, float], dict[str, float]]:
    """Mean and standard deviation (sample, ddof=1; 0 for one run) of every scalar metric over
    runs (seeds or splits). Per-run interval bounds are not aggregated (see ``PER_RUN_ONLY``)."""
    scalars = [scalar_metrics(metrics) for metrics in per_seed]
    if not scalars:
        return {}, {}
    keys = [key for key in scalars[0] if key not in PER_RUN_ONLY and all(key in s for s in scalars)]
    mean, std = {}, {}
    for key in keys:
        values = np.array([s[key] for s in scalars], dtype=np.float64)
        mean[key] = float(np.mean(values))
        std[key] = float(np.std(values, ddof=1)) if len(values) > 1 else 0.0
    # The correlation is nested; lift its r so that it, too, gets a mean and std.
    correlations = [m.get("cardinality_accuracy", {}).get("r") for m in per_seed]
    if all(isinstance(r, float) for r in correlations):
        values = np.array(correlations)
        mean["cardinality_accuracy_r"] = float(np.mean(values))
        std["cardinality_accuracy_r"] = float(np.std(values, ddof=1)) if len(values) > 1 else 0.0
    return mean, std


def mean_interval(values: Sequence[float], confidence: float = 0.95) -> dict[str, float]:
    """Mean, sample std and the two-sided t interval of the mean over independent runs (splits).

    ``half_width`` = t_{n-1, (1+confidence)/2} * std / sqrt(n); NaN bounds for n < 2 (one split
    says nothing about the spread). NaN values are left out and counted in ``n_missing``.
    """
    array = np.asarray([v for v in values if v is not None], dtype=np.float64)
    finite = array[np.isfinite(array)]
    n = len(finite)
    result = {"mean": math.nan, "std": math.nan, "n": n, "low": math.nan, "high": math.nan,
              "half_width": math.nan, "n_missing": int(len(array) - n)}  # fmt: skip
    if n == 0:
        return result
    result["mean"] = float(finite.mean())
    if n >= 2:
        std = float(finite.std(ddof=1))
        half = float(stats.t.ppf(0.5 + confidence / 2, n - 1) * std / math.sqrt(n))
        result.update(std=std, half_width=half, low=result["mean"] - half, high=result["mean"] + half)
    return result


def paired_comparison(model: Sequence[float], reference: Sequence[float], confidence: float = 0.95) -> dict[str, Any]:
    """Model minus reference on the same splits: the mean difference with its t interval, the
    Wilcoxon signed-rank test (two-sided; exact for small n, zero differences split), and the
    counts of splits won, tied and lost. ``resolved`` is +1 / -1 when the interval lies above /
    below 0, else 0."""
    a, b = np.asarray(model, dtype=np.float64), np.asarray(reference, dtype=np.float64)
    if a.shape != b.shape:
        raise ValueError(f"paired comparison needs one value per split for both, got {a.shape} and {b.shape}")
    keep = np.isfinite(a) & np.isfinite(b)
    diff = a[keep] - b[keep]
    interval = mean_interval(diff, confidence)
    result: dict[str, Any] = {"diff": interval, "wins": int((diff > 0).sum()), "ties": int((diff == 0).sum()),
                              "losses": int((diff < 0).sum()), "wilcoxon_p": math.nan, "resolved": 0}  # fmt: skip
    if len(diff) >= 2 and np.any(diff != 0):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            result["wilcoxon_p"] = float(stats.wilcoxon(diff, zero_method="zsplit").pvalue)
    elif len(diff) >= 2:
        result["wilcoxon_p"] = 1.0
    if math.isfinite(interval["low"]):
        result["resolved"] = 1 if interval["low"] > 0 else -1 if interval["high"] < 0 else 0
    return result


# --- Across models ---------------------------------------------------------------------------


def fleiss_kappa(counts: np.ndarray) -> float:
    """Fleiss' kappa of a (items, categories) table of how many raters put each item in each
    category (every row sums to the same number of raters n >= 2).

        P_i = (sum_j n_ij^2 - n) / (n (n - 1)),  P_bar = mean_i P_i,
        p_j = sum_i n_ij / (N n),                P_e = sum_j p_j^2,
        kappa = (P_bar - P_e) / (1 - P_e).

    NaN when there are no items or P_e = 1 (every rating in one category).
    """
    counts = np.asarray(counts, dtype=np.float64)
    if counts.ndim != 2 or len(counts) == 0:
        return math.nan
    raters = counts.sum(axis=1)
    if not np.allclose(raters, raters[0]) or raters[0] < 2:
        raise ValueError(f"every item needs the same number (>= 2) of ratings, got {sorted(set(raters.tolist()))}")
    n = raters[0]
    agreement = ((counts**2).sum(axis=1) - n) / (n * (n - 1))
    p_bar = agreement.mean()
    category_share = counts.sum(axis=0) / counts.sum()
    p_e = float((category_share**2).sum())
    if math.isclose(p_e, 1.0):
        return math.nan
    return float((p_bar - p_e) / (1.0 - p_e))


def misclassification_agreement(
    y_true: Sequence[int], predictions: Mapping[str, Sequence[int]], num_classes: int
) -> dict[str, Any]:
    """Do models that all fail on a clip fail the same way? (thesis 4.4)

    Items = the clips misclassified by *every* model in ``predictions`` (model name -> predicted
    class ids, aligned with ``y_true``). Raters = the models; a rater's category for an item = the
    class it (wrongly) predicted. Returns Fleiss' kappa over those ratings: 1 = the models always
    pick the same wrong class, ~0 = no more agreement than chance given how often each wrong
    class is picked. Also ``num_items``, ``num_all_wrong``, ``num_models``, ``note``.
    """
    y_true = np.asarray(y_true, dtype=np.int64)
    names = list(predictions)
    result: dict[str, Any] = {"kappa": math.nan, "num_items": int(len(y_true)), "num_all_wrong": 0, "num_models": len(names), "models": names, "note": ""}
    if len(names) < 2:
        result["note"] = "undefined: needs at least 2 models"
        return result
    predicted = np.stack([np.asarray(predictions[name], dtype=np.int64) for name in names], axis=1)  # (items, models)
    if predicted.shape[0] != len(y_true):
        raise ValueError(f"every model needs one prediction per item ({len(y_true)}), got {predicted.shape[0]}")
    all_wrong = (predicted != y_true[:, None]).all(axis=1)
    result["num_all_wrong"] = int(all_wrong.sum())
    if not all_wrong.any():
        result["note"] = "undefined: no item is misclassified by every model"
        return result
    counts = np.zeros((int(all_wrong.sum()), num_classes), dtype=np.int64)
    for row, labels in enumerate(predicted[all_wrong]):
        np.add.at(counts[row], labels, 1)
    result["kappa"] = fleiss_kappa(counts)
    if math.isnan(result["kappa"]):
        result["note"] = "undefined: every model predicted the same single class on every such item"
    return result


def pairwise_error_overlap(results: Mapping[str, tuple[Sequence[str], Sequence[bool]]]) -> dict[str, Any]:
    """How often a clip misclassified for one property is also misclassified for another (one
    model; not the thesis' "mutual misclassification", see :func:`mutual_misclassification`).

    ``results``: property -> (video_ids, correct flags) of one model's test predictions. For each
    ordered pair (a, b) over the clips present in both: ``rate`` = |wrong in a and wrong in b| /
    |wrong in a| (NaN when nothing was wrong in a). Returns
    ``{"properties": [...], "rate": {a: {b: rate}}, "counts": {a: {b: {"common", "wrong_a", "wrong_both"}}}}``.
    """
    wrong_sets: dict[str, tuple[set[str], set[str]]] = {}
    for name, (video_ids, correct) in results.items():
        video_ids = [str(v) for v in video_ids]
        if len(video_ids) != len(correct):
            raise ValueError(f"property '{name}': {len(video_ids)} video_ids but {len(correct)} correct flags")
        if len(set(video_ids)) != len(video_ids):
            raise ValueError(f"property '{name}': duplicate video_ids (pass one seed's predictions)")
        wrong_sets[name] = (set(video_ids), {v for v, ok in zip(video_ids, correct) if not bool(ok)})
    names = list(results)
    rate: dict[str, dict[str, float]] = {}
    counts: dict[str, dict[str, dict[str, int]]] = {}
    for a in names:
        rate[a], counts[a] = {}, {}
        for b in names:
            common = wrong_sets[a][0] & wrong_sets[b][0]
            wrong_a = wrong_sets[a][1] & common
            wrong_both = wrong_a & wrong_sets[b][1]
            rate[a][b] = len(wrong_both) / len(wrong_a) if wrong_a else math.nan
            counts[a][b] = {"common": len(common), "wrong_a": len(wrong_a), "wrong_both": len(wrong_both)}
    return {"properties": names, "rate": rate, "counts": counts}


def mutual_misclassification(
    test_sets: Mapping[str, Mapping[str, Mapping[str, bool]]], sizes: Sequence[int] = (2, 3)
) -> dict[str, Any]:
    """The thesis' mutual misclassification (section 4.4, THESIS.md 2.1): the share of the clips
    that are in the test sets of m tasks and are misclassified by all models for all those tasks.

    ``test_sets``: task (property) -> model -> video_id -> correct, every model of a task on that
    task's test set. A clip is "in the test sets of m tasks" when exactly m tasks test it (our
    reading of "in the test sets of 2 (3) tasks"); it counts as mutually misclassified when, for
    each of those tasks, every model got it wrong. For each m in ``sizes``: ``clips`` (in exactly m
    test sets), ``all_wrong`` and ``share`` (NaN without such clips).
    """
    tested: dict[str, list[str]] = {}
    all_wrong: dict[str, dict[str, bool]] = {}
    for task, models in test_sets.items():
        if not models:
            continue
        common = set.intersection(*(set(preds) for preds in models.values()))
        all_wrong[task] = {vid: all(not models[m][vid] for m in models) for vid in common}
        for vid in common:
            tested.setdefault(vid, []).append(task)
    result: dict[str, Any] = {"tasks": sorted(all_wrong), "models": {t: sorted(test_sets[t]) for t in sorted(all_wrong)}}
    for size in sizes:
        clips = [vid for vid, tasks in tested.items() if len(tasks) == size]
        wrong = [vid for vid in clips if all(all_wrong[t][vid] for t in tested[vid])]
        result[str(size)] = {"clips": len(clips), "all_wrong": len(wrong),
                             "share": len(wrong) / len(clips) if clips else math.nan}  # fmt: skip
    return result
