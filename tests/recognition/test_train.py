"""The trainer: early stopping, best-state restore, class weights, callbacks, checkpoints."""

from __future__ import annotations

import numpy as np
import optuna
import pytest
import torch
from recognition_data import TINY_PARAMS

from aslexp.recognition.metrics import mcc
from aslexp.recognition.models import build_classifier
from aslexp.recognition.train import (
    ArraySplit,
    TrainerConfig,
    fit,
    fit_final,
    inverse_frequency_weights,
    load_checkpoint,
    save_checkpoint,
)

TRAINER = {"max_epochs": 4, "patience": 10, "batch_size": 16, "num_threads": 1, "lr": 3e-3}


def _splits(data):
    return tuple(ArraySplit.from_dataset(data, data.splits[name]) for name in ("train", "val", "test"))


def _build(data, name, params=None, seed=0):
    torch.manual_seed(seed)
    _, channels, frames, nodes, _ = data.X.shape
    return build_classifier(name, TINY_PARAMS[name] if params is None else params, channels, frames, nodes, data.num_classes, data.layout)


def test_early_stopping_stops_after_patience_epochs_without_gain(gloss_dataset):
    train, val, _ = _splits(gloss_dataset)
    # lr 0: the weights never change, so val MCC never beats epoch 1.
    result = fit(_build(gloss_dataset, "mlp"), train, val, {**TRAINER, "lr": 0.0, "max_epochs": 30, "patience": 3})
    assert result.stopped_early
    assert result.epochs_run == 4 and result.best_epoch == 1


def test_best_state_is_restored(gloss_dataset):
    train, val, _ = _splits(gloss_dataset)
    model = _build(gloss_dataset, "gru")
    result = fit(model, train, val, {**TRAINER, "max_epochs": 6, "lr": 1e-2})
    val_mccs = [row["val_mcc"] for row in result.history]
    assert result.best_val_mcc == max(val_mccs) and result.best_epoch == 1 + int(np.argmax(val_mccs))
    assert mcc(val.y, model.predict(val.X, val.mask)) == pytest.approx(result.best_val_mcc)
    assert set(result.history[0]) == {"epoch", "train_loss", "train_accuracy", "val_accuracy", "val_mcc", "lr", "epoch_time", "clips_per_s"}
    assert result.best_val_score == result.best_val_mcc and result.selection_metric == "mcc"


def test_same_seed_same_run(gloss_dataset):
    train, val, _ = _splits(gloss_dataset)
    runs = [fit(_build(gloss_dataset, "stgcn", seed=3), train, val, {**TRAINER, "max_epochs": 2}, seed=3) for _ in range(2)]
    assert [r["train_loss"] for r in runs[0].history] == [r["train_loss"] for r in runs[1].history]


def test_step_lr_schedule(gloss_dataset):
    train, _, test = _splits(gloss_dataset)
    final = fit_final(_build(gloss_dataset, "mlp"), train, test, {**TRAINER, "lr_step_size": 1, "lr_gamma": 0.5}, epochs=3)
    assert [row["lr"] for row in final.fit.history] == pytest.approx([3e-3, 1.5e-3, 7.5e-4])
    assert final.fit.epochs_run == 3 and final.y_pred.shape == (len(test),)


def test_inverse_frequency_class_weights(gloss_dataset):
    np.testing.assert_allclose(inverse_frequency_weights(np.array([0, 0, 0, 1]), 3), [4 / (2 * 3), 4 / (2 * 1), 0.0])
    train, val, _ = _splits(gloss_dataset)
    # Make the training set imbalanced: keep one clip of class 3.
    keep = np.concatenate([np.flatnonzero(train.y != 3), np.flatnonzero(train.y == 3)[:1]])
    imbalanced = ArraySplit(train.X[keep], train.mask[keep], train.y[keep])
    config = {**TRAINER, "max_epochs": 1}
    plain = fit(_build(gloss_dataset, "mlp"), imbalanced, val, config)
    weighted = fit(_build(gloss_dataset, "mlp"), imbalanced, val, {**config, "class_weights": True})
    assert plain.history[0]["train_loss"] != pytest.approx(weighted.history[0]["train_loss"])
    # A linear model with balanced weights predicts the rare class at least as often.
    predictions = {}
    for weighted_loss in (False, True):
        model = _build(gloss_dataset, "logreg", {"pooling": "mean_std", "C": 0.05})
        fit(model, imbalanced, val, {**config, "class_weights": weighted_loss})
        predictions[weighted_loss] = int((model.predict(gloss_dataset.X, gloss_dataset.mask) == 3).sum())
    assert predictions[True] >= predictions[False] and predictions[True] > 0


class Abort(RuntimeError):
    pass


def test_callback_sees_every_epoch_and_can_abort_training(gloss_dataset):
    train, val, _ = _splits(gloss_dataset)
    seen = []

    def on_epoch_end(epoch, val_mcc):
        seen.append((epoch, val_mcc))
        if epoch == 2:
            raise Abort("stop here")

    with pytest.raises(Abort, match="stop here"):
        fit(_build(gloss_dataset, "stgcn"), train, val, TRAINER, on_epoch_end=on_epoch_end)
    assert [epoch for epoch, _ in seen] == [1, 2]

    def prune(epoch, val_mcc):
        raise optuna.TrialPruned(f"pruned at epoch {epoch}")

    with pytest.raises(optuna.TrialPruned):
        fit(_build(gloss_dataset, "svm"), train, val, TRAINER, on_epoch_end=prune)


@pytest.mark.parametrize("name", ["stgcn", "logreg"])
def test_checkpoint_roundtrip_reproduces_predictions(gloss_dataset, tmp_path, name):
    train, val, test = _splits(gloss_dataset)
    model = _build(gloss_dataset, name)
    fit(model, train, val, {**TRAINER, "max_epochs": 1})
    path = save_checkpoint(model, tmp_path / f"model{model.checkpoint_suffix}", extra={"epochs": 1})
    loaded, extra = load_checkpoint(path)
    assert extra == {"epochs": 1} and loaded.spec == model.spec
    np.testing.assert_allclose(loaded.predict_proba(test.X, test.mask), model.predict_proba(test.X, test.mask), rtol=1e-6)


def test_trainer_config_rejects_unknown_keys():
    with pytest.raises(ValueError, match="trainer.epochs=3: unknown key; did you mean trainer.max_epochs\\?"):
        TrainerConfig.parse({"epochs": 3})
    assert TrainerConfig.parse({"lr": "0.01", "class_weights": 1}).lr == 0.01


def test_the_deterministic_flag_is_set_without_importing_the_compiler():
    """seed_everything's flag is torch's (kernels deterministic, warnings only) without the ~1.5 s
    import of torch._inductor that torch.use_deterministic_algorithms makes; where the compiler is
    already imported its flag follows too."""
    import subprocess
    import sys

    probe = ("import sys, torch\n"
             "from aslexp.seeding import seed_everything\n"
             "seed_everything(0, True)\n"
             "print(torch.are_deterministic_algorithms_enabled(), torch.is_deterministic_algorithms_warn_only_enabled(),\n"
             "      'torch._inductor' in sys.modules)\n"
             "import torch._inductor.config as inductor\n"
             "seed_everything(0, False)\n"
             "print(torch.are_deterministic_algorithms_enabled(), inductor.deterministic)\n"
             "seed_everything(0, True)\n"
             "print(inductor.deterministic)\n")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, check=True).stdout
    assert out.split() == ["True", "True", "False", "False", "False", "True"]
