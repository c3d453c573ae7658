"""Metrics against hand-computed values and scikit-learn on small known examples."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from sklearn.metrics import balanced_accuracy_score, f1_score, matthews_corrcoef, precision_score, recall_score

from aslexp.recognition.metrics import (
    accuracy_ci,
    aggregate_over_seeds,
    cardinality_accuracy_correlation,
    classification_metrics,
    fleiss_kappa,
    misclassification_agreement,
    pairwise_error_overlap,
)

LABELS = ["a", "b", "c"]
Y_TRUE = [0, 0, 0, 1, 1, 1, 2, 2]
Y_PRED = [0, 0, 1, 1, 1, 2, 2, 0]


def test_accuracy_and_confidence_interval_by_hand():
    metrics = classification_metrics(Y_TRUE, Y_PRED, LABELS)
    p = 5 / 8
    half = 1.96 * math.sqrt(p * (1 - p) / 8)
    assert metrics["n"] == 8
    assert metrics["accuracy"] == pytest.approx(p)
    assert metrics["accuracy_ci_low"] == pytest.approx(p - half, abs=1e-4)
    assert metrics["accuracy_ci_high"] == pytest.approx(p + half, abs=1e-4)
    assert accuracy_ci(8, 8) == (1.0, 1.0, 1.0)  # p(1-p) = 0: a point
    assert accuracy_ci(1, 10)[1] == 0.0  # clipped at 0


def test_scores_match_sklearn():
    metrics = classification_metrics(Y_TRUE, Y_PRED, LABELS)
    assert metrics["mcc"] == pytest.approx(matthews_corrcoef(Y_TRUE, Y_PRED))
    assert metrics["balanced_accuracy"] == pytest.approx(balanced_accuracy_score(Y_TRUE, Y_PRED))
    for average in ("micro", "macro"):
        assert metrics[f"f1_{average}"] == pytest.approx(f1_score(Y_TRUE, Y_PRED, average=average))
        assert metrics[f"precision_{average}"] == pytest.approx(precision_score(Y_TRUE, Y_PRED, average=average))
        assert metrics[f"recall_{average}"] == pytest.approx(recall_score(Y_TRUE, Y_PRED, average=average))
    assert metrics["confusion_matrix"] == [[2, 1, 0], [0, 2, 1], [1, 0, 1]]


def test_binary_mcc_by_hand():
    # TP 2, FN 1, FP 1, TN 4: (2*4 - 1*1) / sqrt(3 * 3 * 5 * 5) = 7/15
    metrics = classification_metrics([1, 1, 1, 0, 0, 0, 0, 0], [1, 1, 0, 1, 0, 0, 0, 0], ["no", "yes"])
    assert metrics["mcc"] == pytest.approx(7 / 15)


def test_per_class_rows_and_cardinality_correlation():
    metrics = classification_metrics(Y_TRUE, Y_PRED, LABELS)
    rows = {row["label"]: row for row in metrics["per_class"]}
    assert rows["a"] == {"label": "a", "support": 3, "predicted": 3, "correct": 2, "thesis_a": 2 / 8,
                         "precision": 2 / 3, "recall": 2 / 3, "f1": pytest.approx(2 / 3)}
    assert rows["c"]["support"] == 2 and rows["c"]["recall"] == 0.5 and rows["c"]["precision"] == 0.5
    # The thesis' per-class A = TP_c / N_test sums to the accuracy (THESIS.md 2.5); recall does not.
    assert sum(row["thesis_a"] for row in rows.values()) == pytest.approx(metrics["accuracy"])
    assert metrics["cardinality_thesis_a"]["r"] == pytest.approx(np.corrcoef([3, 3, 2], [2 / 8, 2 / 8, 1 / 8])[0, 1])
    support, accuracy = [3, 3, 2], [2 / 3, 2 / 3, 1 / 2]
    r = np.corrcoef(support, accuracy)[0, 1]
    assert metrics["cardinality_accuracy"]["r"] == pytest.approx(r)
    assert 0.0 <= metrics["cardinality_accuracy"]["p_value"] <= 1.0
    json.dumps(metrics)


def test_correlation_is_nan_with_a_note_when_undefined():
    two = cardinality_accuracy_correlation([3, 5], [0.5, 0.2])
    assert math.isnan(two["r"]) and "need >= 3" in two["note"]
    flat = cardinality_accuracy_correlation([3, 5, 4], [0.5, 0.5, 0.5])
    assert math.isnan(flat["r"]) and "accuracy is the same" in flat["note"]
    # Classes absent from the test set do not take part.
    absent = cardinality_accuracy_correlation([0, 3, 5, 4], [math.nan, 0.1, 0.5, 0.3])
    assert absent["num_classes"] == 3 and not math.isnan(absent["r"])


def test_fleiss_kappa_textbook_example():
    # Fleiss (1971) as tabulated on Wikipedia: 10 subjects, 14 raters, 5 categories -> 0.210.
    counts = [
        [0, 0, 0, 0, 14], [0, 2, 6, 4, 2], [0, 0, 3, 5, 6], [0, 3, 9, 2, 0], [2, 2, 8, 1, 1],
        [7, 7, 0, 0, 0], [3, 2, 6, 3, 0], [2, 5, 3, 2, 2], [6, 5, 2, 1, 0], [0, 2, 2, 3, 7],
    ]
    assert fleiss_kappa(counts) == pytest.approx(0.210, abs=5e-4)
    assert fleiss_kappa([[3, 0], [0, 3]]) == pytest.approx(1.0)
    assert math.isnan(fleiss_kappa([[3, 0], [3, 0]]))  # one category only: undefined


def test_misclassification_agreement_on_items_all_models_get_wrong():
    y_true = [0, 0, 1, 1, 2]
    predictions = {"A": [1, 0, 2, 0, 0], "B": [1, 1, 2, 2, 1], "C": [2, 0, 0, 0, 0]}
    result = misclassification_agreement(y_true, predictions, num_classes=3)
    # Item 1 is right for A and C, so items 0, 2, 3, 4 remain; their ratings per class:
    # [0,2,1], [1,0,2], [2,0,1], [2,1,0] -> P_bar = 1/3, P_e = (5^2+3^2+4^2)/12^2 = 50/144.
    assert result["num_all_wrong"] == 4 and result["num_models"] == 3
    assert result["kappa"] == pytest.approx((1 / 3 - 50 / 144) / (1 - 50 / 144))
    none_wrong = misclassification_agreement([0, 1], {"A": [0, 1], "B": [1, 1]}, 2)
    assert math.isnan(none_wrong["kappa"]) and "no item" in none_wrong["note"]


def test_pairwise_error_overlap_by_hand():
    results = {
        "sign_type": (["v1", "v2", "v3", "v4"], [False, False, True, True]),
        "location": (["v2", "v3", "v4", "v5"], [False, False, True, False]),
    }
    result = pairwise_error_overlap(results)
    # Common clips v2, v3, v4. Wrong in sign_type: v2 (also wrong in location) -> 1/1.
    assert result["rate"]["sign_type"]["location"] == 1.0
    # Wrong in location among the common clips: v2, v3; v2 also wrong in sign_type -> 1/2.
    assert result["rate"]["location"]["sign_type"] == 0.5
    assert result["counts"]["location"]["sign_type"] == {"common": 3, "wrong_a": 2, "wrong_both": 1}
    assert result["rate"]["sign_type"]["sign_type"] == 1.0
    json.dumps(result)
    with pytest.raises(ValueError, match="duplicate video_ids"):
        pairwise_error_overlap({"p": (["v1", "v1"], [True, False])})


def test_aggregate_over_seeds_mean_and_sample_std():
    first = classification_metrics([0, 1, 0, 1], [0, 1, 1, 1], ["a", "b"])  # accuracy 0.75
    second = classification_metrics([0, 1, 0, 1], [0, 1, 0, 1], ["a", "b"])  # accuracy 1.0
    mean, std = aggregate_over_seeds([first, second])
    assert mean["accuracy"] == pytest.approx(0.875)
    assert std["accuracy"] == pytest.approx(np.std([0.75, 1.0], ddof=1))
    assert "confusion_matrix" not in mean
    # Per-run Wald bounds are not averaged into something that looks like an interval.
    assert "accuracy_ci_low" not in mean and "accuracy_ci_high" not in std
