"""Intervals over splits, paired comparisons, and the thesis' mutual misclassification, by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from aslexp.recognition.metrics import mean_interval, mutual_misclassification, paired_comparison, selection_score


def test_t_interval_of_the_mean():
    values = [0.52, 0.61, 0.48, 0.70, 0.55]
    result = mean_interval(values)
    low, high = stats.t.interval(0.95, 4, loc=np.mean(values), scale=stats.sem(values))
    assert result["mean"] == pytest.approx(np.mean(values)) and result["n"] == 5
    assert (result["low"], result["high"]) == pytest.approx((low, high))
    assert result["std"] == pytest.approx(np.std(values, ddof=1))
    one = mean_interval([0.4])
    assert one["mean"] == 0.4 and math.isnan(one["low"]) and math.isnan(one["half_width"])
    assert mean_interval([0.4, float("nan"), 0.6])["n_missing"] == 1


def test_paired_comparison_on_the_same_splits():
    model = [0.60, 0.55, 0.70, 0.65, 0.58, 0.62]
    reference = [0.50, 0.52, 0.61, 0.55, 0.57, 0.50]
    result = paired_comparison(model, reference)
    diff = np.subtract(model, reference)
    assert result["diff"]["mean"] == pytest.approx(diff.mean())
    assert result["wins"] == 6 and result["losses"] == 0 and result["resolved"] == 1
    assert result["wilcoxon_p"] == pytest.approx(stats.wilcoxon(diff).pvalue)
    # Swapping the roles flips the sign; a shared offset of the splits cancels.
    assert paired_comparison(reference, model)["resolved"] == -1
    noisy = paired_comparison([0.5, 0.7, 0.4, 0.6], [0.55, 0.6, 0.45, 0.62])
    assert noisy["resolved"] == 0 and noisy["diff"]["low"] < 0 < noisy["diff"]["high"]
    assert paired_comparison([0.5, 0.5], [0.5, 0.5])["wilcoxon_p"] == 1.0
    with pytest.raises(ValueError, match="one value per split"):
        paired_comparison([0.5], [0.5, 0.6])


def test_the_thesis_mutual_misclassification_by_hand():
    # Three tasks, two models each; True = correct.
    test_sets = {
        "flexion": {"mlp": {"a": False, "b": False, "c": True, "d": False},
                    "gru": {"a": False, "b": True, "c": True, "d": False}},
        "sign_type": {"mlp": {"a": False, "b": False, "e": False},
                      "gru": {"a": False, "b": False, "e": False}},
        "movement": {"mlp": {"a": False, "d": True, "f": False},
                     "gru": {"a": False, "d": False, "f": True}},
    }  # fmt: skip
    result = mutual_misclassification(test_sets)
    # In exactly 2 test sets: b (flexion, sign_type), d (flexion, movement). b: flexion has gru right.
    # d: movement has mlp right. -> 0 of 2.
    assert result["2"] == {"clips": 2, "all_wrong": 0, "share": 0.0}
    # In 3 test sets: a, wrong for every model in every task -> 1 of 1.
    assert result["3"] == {"clips": 1, "all_wrong": 1, "share": 1.0}
    assert result["tasks"] == ["flexion", "movement", "sign_type"]


@pytest.mark.parametrize("metric", ["mcc", "accuracy", "balanced_accuracy", "f1_micro", "f1_macro"])
def test_selection_scores(metric):
    from sklearn import metrics

    y_true, y_pred = [0, 0, 1, 1, 2, 2, 2], [0, 1, 1, 1, 2, 0, 2]
    reference = {"mcc": metrics.matthews_corrcoef, "accuracy": metrics.accuracy_score,
                 "balanced_accuracy": metrics.balanced_accuracy_score,
                 "f1_micro": lambda a, b: metrics.f1_score(a, b, average="micro"),
                 "f1_macro": lambda a, b: metrics.f1_score(a, b, average="macro")}[metric]  # fmt: skip
    assert selection_score(y_true, y_pred, metric) == pytest.approx(reference(y_true, y_pred))
