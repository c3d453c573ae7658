"""run_recognition end to end on real keypoints, and the thesis table."""

from __future__ import annotations

import csv
import json

import numpy as np
import optuna
import pytest
from sklearn.model_selection import StratifiedKFold

from aslexp.recognition.experiment import run_recognition
from aslexp.recognition.metrics import pairwise_error_overlap

TRAINER = {"max_epochs": 3, "patience": 5, "batch_size": 16, "num_threads": 1, "lr": 5e-3}


def test_holdout_run_writes_every_artefact(gloss_dataset, tmp_path):
    calls = []
    result = run_recognition(
        gloss_dataset, {"name": "gru", "params": {"hidden_size": 16, "num_layers": 1}}, TRAINER, seeds=[0, 1],
        out_dir=tmp_path, on_epoch_end=lambda epoch, val_mcc: calls.append((epoch, val_mcc)),
    )
    json.dumps(result)
    for name in ("per_class.csv", "predictions.csv", "confusion_matrix.png", "learning_curves.png", "model.pt"):
        assert (tmp_path / name).stat().st_size > 0, name
    assert result["validation"] == "holdout" and result["seeds"] == [0, 1]
    # The callback saw exactly the first seed's validation epochs.
    assert [epoch for epoch, _ in calls] == [row["epoch"] for row in result["history"]["seed 0"]]
    assert result["val_mcc"] == pytest.approx(np.mean([record["mcc"] for record in result["val"]]))
    n_test = len(gloss_dataset.splits["test"])
    assert result["test"]["n"] == n_test and 0.0 <= result["test"]["accuracy"] <= 1.0
    assert result["test"]["accuracy"] == pytest.approx(np.mean([m["accuracy"] for m in result["test_per_seed"]]))
    assert set(result["test_std"]) == set(result["test"])
    assert result["baseline"]["name"] in ("majority", "stratified")
    assert result["baselines"]["majority"]["test"]["mcc"] == 0.0
    # The final models trained for the validated epoch count.
    for record in result["val"]:
        assert len(result["final_history"][f"seed {record['seed']}"]) == record["best_epoch"]

    with open(tmp_path / "predictions.csv") as handle:
        predictions = list(csv.DictReader(handle))
    assert len(predictions) == 2 * n_test
    assert set(predictions[0]) == {"video_id", "true", "predicted", "split", "seed", "correct"}
    first_seed = [row for row in predictions if row["seed"] == "0"]
    accuracy = np.mean([row["true"] == row["predicted"] for row in first_seed])
    assert accuracy == pytest.approx(result["test_per_seed"][0]["accuracy"])
    with open(tmp_path / "per_class.csv") as handle:
        per_class = list(csv.DictReader(handle))
    assert len(per_class) == 3 * gloss_dataset.num_classes  # two seeds + their mean
    assert set(per_class[0]) >= {"thesis_a", "recall", "support"}
    assert sum(int(row["support"]) for row in per_class if row["seed"] == "0") == n_test

    # Mutual misclassification over two "properties" from the same predictions file.
    ids = [row["video_id"] for row in first_seed]
    correct = [row["correct"] == "1" for row in first_seed]
    mutual = pairwise_error_overlap({"gloss": (ids, correct), "gloss_again": (ids, correct)})
    if not all(correct):
        assert mutual["rate"]["gloss"]["gloss_again"] == 1.0


def test_cv5_validation_is_the_mean_over_folds(gloss_dataset, tmp_path):
    data = gloss_dataset
    train_val = np.asarray(data.splits["train+val"])
    folds = [
        (train_val[fit_idx], train_val[val_idx])
        for fit_idx, val_idx in StratifiedKFold(5, shuffle=True, random_state=0).split(train_val, data.y[train_val])
    ]
    splits = {"train+val": train_val, "test": data.splits["test"], "folds": folds}
    cv_data = type(data)(**{**data.__dict__, "splits": splits})
    result = run_recognition(cv_data, {"name": "logreg", "params": {"pooling": "mean_std"}}, TRAINER, [0], tmp_path)
    record = result["val"][0]
    assert result["validation"] == "cv5" and len(record["fold_mcc"]) == 5
    assert result["val_mcc"] == pytest.approx(np.mean(record["fold_mcc"]))
    assert (tmp_path / "model.joblib").is_file()

    bad = type(data)(**{**data.__dict__, "splits": {**splits, "folds": [(train_val, data.splits["test"])]}})
    with pytest.raises(ValueError, match="outside 'train\\+val'"):
        run_recognition(bad, {"name": "logreg"}, TRAINER, [0], tmp_path / "bad")


def test_pruning_from_a_real_optuna_trial_propagates(gloss_dataset, tmp_path):
    def objective(trial: optuna.Trial) -> float:
        def report(epoch: int, val_mcc: float) -> None:
            trial.report(val_mcc, epoch)
            raise optuna.TrialPruned()  # as a pruner's verdict would

        return run_recognition(gloss_dataset, {"name": "mlp", "params": {"hidden_sizes": [8]}}, TRAINER, [0], tmp_path, report)["val_mcc"]

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    study = optuna.create_study(direction="maximize")
    study.optimize(objective, n_trials=1)
    trial = study.trials[0]
    assert trial.state == optuna.trial.TrialState.PRUNED and list(trial.intermediate_values) == [1]
