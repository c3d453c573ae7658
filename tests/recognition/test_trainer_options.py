"""Trainer options every model can use: SGD/Nesterov, warm-up and milestones, augmentation,
selection metric, fixed-budget training, the smoothed retrain budget."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from recognition_data import TINY_PARAMS

from aslexp.recognition.augment import random_shift, random_temporal_crop
from aslexp.recognition.metrics import selection_score
from aslexp.recognition.models import build_classifier
from aslexp.recognition.train import (
    ArraySplit,
    TrainerConfig,
    _batches,
    fit,
    fit_final,
    learning_rate,
    make_optimizer,
    smoothed_best_epoch,
)

SLGCN_SCHEDULE = {"optimizer": "sgd", "lr": 0.1, "nesterov": True, "lr_schedule": "multistep", "lr_gamma": 0.1,
                  "lr_milestones": [120, 140], "warmup_epochs": 20}  # fmt: skip


def _build(data, name, seed=0):
    torch.manual_seed(seed)
    return build_classifier(name, TINY_PARAMS[name], 3, data.X.shape[2], data.X.shape[3], data.num_classes, data.layout)


def test_slgcn_learning_rate_schedule_matches_the_authors():
    config = TrainerConfig.parse(SLGCN_SCHEDULE)

    def authors(epoch):  # SL-GCN main.py adjust_learning_rate
        if epoch < 20:
            return 0.1 * (epoch + 1) / 20
        return 0.1 * (0.1 ** np.sum(epoch >= np.array([120, 140])))

    for epoch in (0, 1, 19, 20, 119, 120, 139, 140, 149):
        assert learning_rate(config, epoch) == pytest.approx(authors(epoch))
    optimizer = make_optimizer(torch.nn.Linear(2, 2), config)
    assert isinstance(optimizer, torch.optim.SGD)
    assert optimizer.defaults["nesterov"] and optimizer.defaults["momentum"] == 0.9


def test_the_trainer_applies_warm_up_and_milestones(gloss_dataset):
    data = gloss_dataset
    train, test = (ArraySplit.from_dataset(data, data.splits[s]) for s in ("train", "test"))
    config = {**SLGCN_SCHEDULE, "lr_milestones": [3], "warmup_epochs": 2, "batch_size": 16, "num_threads": 1}
    final = fit_final(_build(data, "mlp"), train, test, config, epochs=5)
    assert [row["lr"] for row in final.fit.history] == pytest.approx([0.05, 0.1, 0.1, 0.01, 0.01])


def test_random_temporal_crop_takes_consecutive_observed_frames():
    generator = torch.Generator().manual_seed(0)
    frames = torch.arange(1, 11, dtype=torch.float32)  # values 1..10 in frames 0..9
    x = frames.view(1, 1, 10, 1).repeat(64, 2, 1, 3)
    mask = torch.ones(64, 10, 3)
    mask[:32, 6:] = 0  # the first 32 clips end after 6 frames (zero padding)
    x[:32, :, 6:] = 0
    cropped, cropped_mask = random_temporal_crop(x, mask, 4, generator)
    assert cropped.shape == (64, 2, 4, 3) and cropped_mask.shape == (64, 4, 3)
    first = cropped[:, 0, :, 0]
    assert torch.equal(first[:, 1:] - first[:, :-1], torch.ones(64, 3))  # consecutive frames
    assert first[:32].max() <= 6 and bool((cropped_mask > 0).all())  # never the padding
    assert len(set(first[:, 0].tolist())) > 3  # random starts
    # A window longer than the clip: the clip at a random offset, the rest unobserved zeros.
    long, long_mask = random_temporal_crop(x[:32], mask[:32], 8, generator)
    assert int(long_mask[:, :, 0].sum(dim=1).unique()) == 6
    assert torch.equal(long[:, 0, :, 0][long_mask[:, :, 0] > 0].view(32, 6), frames[:6].repeat(32, 1))


def test_random_shift_moves_observed_points_of_a_clip_together():
    generator = torch.Generator().manual_seed(0)
    x = torch.zeros(16, 3, 5, 4)
    mask = torch.ones(16, 5, 4)
    mask[:, :, 3] = 0
    shifted = random_shift(x, mask, 0.1, (0, 1), generator)
    offsets = shifted[:, :2, 0, 0]
    assert torch.equal(shifted[:, :2, :, :3], offsets[:, :, None, None].expand(-1, -1, 5, 3))
    assert bool((offsets.abs() <= 0.1).all()) and offsets.std() > 0
    assert torch.equal(shifted[:, 2], x[:, 2]) and torch.equal(shifted[..., 3], x[..., 3])  # score, missing


def test_fixed_budget_training_selected_by_micro_f1(gloss_dataset):
    data = gloss_dataset
    train, val = (ArraySplit.from_dataset(data, data.splits[s]) for s in ("train", "val"))
    model = _build(data, "mlp")
    config = {"max_epochs": 3, "early_stopping": False, "selection_metric": "f1_micro", "batch_size": 16, "num_threads": 1}
    result = fit(model, train, val, config)
    assert result.epochs_run == 3 and result.best_epoch == 3 and not result.stopped_early
    assert result.best_val_score == result.history[-1]["val_f1_micro"]
    assert result.best_val_score == pytest.approx(selection_score(val.y, model.predict(val.X, val.mask), "f1_micro"))


def test_smoothed_best_epoch_ignores_a_lone_early_spike():
    history = [{"val_mcc": v} for v in (0.1, 0.9, 0.1, 0.3, 0.5, 0.6, 0.62, 0.6, 0.55)]
    assert smoothed_best_epoch(history, "val_mcc", 1) == 2  # the spike
    assert smoothed_best_epoch(history, "val_mcc", 5) in (6, 7, 8)  # the plateau


def test_drop_last_and_the_lone_last_batch():
    rng = np.random.default_rng(0)
    assert [len(b) for b in _batches(10, 4, rng, drop_last=True)] == [4, 4]
    batches = _batches(9, 4, rng)
    assert [len(b) for b in batches] == [4, 5]  # a batch of 1 joins the previous one
    assert sorted(np.concatenate(batches).tolist()) == list(range(9))  # every clip once
    assert [len(b) for b in _batches(3, 4, rng, drop_last=True)] == [3]  # never the only batch


def test_unknown_choices_are_rejected():
    for key, value in (("optimizer", "rmsprop"), ("lr_schedule", "cosine"), ("selection_metric", "auc"),
                       ("retrain_epochs", "last")):  # fmt: skip
        with pytest.raises(ValueError, match=f"trainer.{key}={value}: expected one of "):
            TrainerConfig.parse({key: value})
    assert TrainerConfig.parse({"lr_milestones": ["120", 140]}).lr_milestones == (120, 140)
