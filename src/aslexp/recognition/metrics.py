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
        [row["support"] for row in per_class], [row["accuracy"] for row in per_class]
    )
    return result


def per_class_metrics(matrix: np.ndarray, label_names: Sequence[str]) -> list[dict[str, Any]]:
    """One dict per class from a confusion matrix (rows true, columns predicted).

    ``support`` = number of true items of the class (its cardinality in the evaluated set);
    ``accuracy`` = share of them classified correctly (= recall; the thesis' per-class accuracy);
    ``precision`` = share of the items predicted as the class that are of the class;
    ``f1`` = 2TP / (support + predicted); ``predicted`` = how often the class was predicted.
    NaN where the denominator is 0.
    """
    matrix = np.asarray(matrix)
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
                "accuracy": recall, "precision": precision, "recall": recall, "f1": f1,
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


def aggregate_over_seeds(per_seed: Sequence[Mapping[str, Any]]) -> tuple[dict[str, float], dict[str, float]]:
    """Mean and standard deviation (sample, ddof=1; 0 for one seed) of every scalar metric."""
    scalars = [scalar_metrics(metrics) for metrics in per_seed]
    if not scalars:
        return {}, {}
    keys = [key for key in scalars[0] if all(key in s for s in scalars)]
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


def mutual_misclassification(results: Mapping[str, tuple[Sequence[str], Sequence[bool]]]) -> dict[str, Any]:
    """How often a clip misclassified for one property is also misclassified for another.

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
