"""Every classifier trains a few steps on real keypoints and yields every metric."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from recognition_data import FAST_TRAINER, POSE_LAYOUT, TINY_PARAMS

from aslexp.recognition.metrics import classification_metrics
from aslexp.recognition.models import CLASSIFIER_NAMES, DEFAULT_PARAMS, HeatmapRenderer, build_classifier, clip_features
from aslexp.recognition.train import ArraySplit, fit


def _build(dataset, name, params):
    _, channels, frames, nodes, _ = dataset.X.shape
    return build_classifier(name, params, channels, frames, nodes, dataset.num_classes, dataset.layout)


def test_registry_lists_every_model():
    assert set(CLASSIFIER_NAMES) == {"majority", "stratified", "logreg", "svm", "rf", "hgb", "mlp", "lstm", "gru", "stgcn",
                                     "slgcn", "cnn3d"}
    assert set(TINY_PARAMS) == set(CLASSIFIER_NAMES)


@pytest.mark.parametrize("name", CLASSIFIER_NAMES)
def test_classifier_trains_and_yields_all_metrics(gloss_dataset, name):
    data = gloss_dataset
    train = ArraySplit.from_dataset(data, data.splits["train"])
    val = ArraySplit.from_dataset(data, data.splits["val"])
    test = ArraySplit.from_dataset(data, data.splits["test"])
    torch.manual_seed(0)
    model = _build(data, name, TINY_PARAMS[name])
    result = fit(model, train, val, FAST_TRAINER, seed=0)

    expected_epochs = 1 if model.kind == "sklearn" else FAST_TRAINER["max_epochs"]
    assert result.epochs_run == expected_epochs
    if model.kind == "torch":
        assert all(np.isfinite(row["train_loss"]) for row in result.history)
    proba = model.predict_proba(test.X, test.mask)
    assert proba.shape == (len(test), data.num_classes)
    np.testing.assert_allclose(proba.sum(axis=1), 1.0, rtol=1e-5)
    y_pred = model.predict(test.X, test.mask)
    assert y_pred.dtype == np.int64 and set(y_pred) <= set(range(data.num_classes))

    metrics = classification_metrics(test.y, y_pred, data.label_names)
    for key in ("accuracy", "accuracy_ci_low", "accuracy_ci_high", "balanced_accuracy", "precision_micro",
                "recall_micro", "f1_micro", "precision_macro", "recall_macro", "f1_macro", "mcc"):
        assert isinstance(metrics[key], float) and 0.0 - 1.0 <= metrics[key] <= 1.0, key
    assert np.array(metrics["confusion_matrix"]).sum() == len(test)
    assert [row["support"] for row in metrics["per_class"]] == np.bincount(test.y, minlength=4).tolist()
    json.dumps(metrics)  # JSON-ready


def test_majority_predicts_the_most_frequent_training_class(gloss_dataset):
    data = gloss_dataset
    train = ArraySplit.from_dataset(data, data.splits["train"])
    model = _build(data, "majority", {})
    model.fit(train.X, train.mask, train.y)
    most_frequent = np.bincount(train.y).argmax()
    assert (model.predict(data.X, data.mask) == most_frequent).all()


def test_unknown_params_and_missing_layout_are_clear_errors(gloss_dataset):
    with pytest.raises(ValueError, match="unknown params \\['hidden'\\]"):
        _build(gloss_dataset, "gru", {"hidden": 3})
    with pytest.raises(ValueError, match="unknown classifier 'transformer'"):
        _build(gloss_dataset, "transformer", {})
    with pytest.raises(ValueError, match="needs the keypoint layout"):
        build_classifier("stgcn", {}, 3, 24, 33, 4, None)
    model = _build(gloss_dataset, "mlp", {})
    with pytest.raises(ValueError, match="X has shape"):
        model.predict(gloss_dataset.X[:, :2], gloss_dataset.mask)


def test_defaults_are_complete_and_overridable():
    model = build_classifier("stgcn", {"channels": [8]}, 3, 24, 33, 4, POSE_LAYOUT)
    assert model.spec.params == {**DEFAULT_PARAMS["stgcn"], "channels": [8]}
    assert DEFAULT_PARAMS["stgcn"]["channels"] == [32, 32, 64, 64, 128]  # the default is not mutated


def test_mean_std_pooling_ignores_missing_frames():
    X = np.zeros((1, 1, 4, 2, 1), dtype=np.float32)
    X[0, 0, :, 0, 0] = [0.5, 0.7, 0.0, 0.0]  # joint 0 observed in the first two frames
    mask = np.zeros((1, 4, 2), dtype=bool)
    mask[0, :2, 0] = True
    features = clip_features(X, mask, "mean_std")  # [mean_j0, mean_j1, std_j0, std_j1]
    np.testing.assert_allclose(features[0], [0.6, 0.0, 0.1, 0.0], atol=1e-6)
    assert clip_features(X, mask, "none").shape == (1, 8)


def test_heatmap_renders_a_blob_where_the_joint_is():
    renderer = HeatmapRenderer(size=9, sigma=0.1, sum_joints=False, xy_channels=(0, 1), frame_stride=1)
    x = torch.zeros(1, 2, 1, 2)
    x[0, :, 0, 0] = torch.tensor([-1.0, 1.0])  # joint 0 at x=-1 (left), y=+1 (bottom row)
    mask = torch.tensor([[[1.0, 0.0]]])  # joint 1 missing
    heat = renderer(x, mask)  # (N, V, T, H, W)
    assert heat.shape == (1, 2, 1, 9, 9)
    row, column = divmod(int(heat[0, 0, 0].argmax()), 9)
    assert (row, column) == (8, 0)
    assert float(heat[0, 0, 0].max()) == pytest.approx(1.0)
    assert float(heat[0, 1].abs().sum()) == 0.0


def test_summary_features_by_hand():
    X = np.zeros((1, 2, 5, 2, 1), dtype=np.float32)
    X[0, 0, :, 0, 0] = [0.1, 0.3, 0.0, 0.6, 0.2]  # channel 0 of joint 0; frame 2 unobserved
    X[0, 1, :, 0, 0] = [1.0, 1.0, 0.0, 1.0, 1.0]
    mask = np.zeros((1, 5, 2), dtype=bool)
    mask[0, [0, 1, 3, 4], 0] = True  # joint 1 never observed
    features = clip_features(X, mask, "summary").reshape(-1)
    # layout: 8 statistics x (C=2 x V=2), then the observed share per joint
    stats = features[:-2].reshape(8, 2, 2)
    observed = np.array([0.1, 0.3, 0.6, 0.2])
    np.testing.assert_allclose(stats[:, 0, 0], [observed.mean(), observed.std(), 0.1, 0.6, 0.5,
                                                # velocities only between consecutive observed frames: 0-1, 3-4
                                                np.mean([0.2, 0.4]), np.std([0.2, -0.4]), 0.4], atol=1e-6)  # fmt: skip
    np.testing.assert_allclose(stats[:, 1, 0], [1, 0, 1, 1, 0, 0, 0, 0], atol=1e-6)
    assert not stats[:, :, 1].any()  # a joint never observed: zeros, not NaN or inf
    np.testing.assert_allclose(features[-2:], [0.8, 0.0])


def test_thesis_variants_of_the_linear_models(gloss_dataset):
    data = gloss_dataset
    train = ArraySplit.from_dataset(data, data.splits["train"])
    ovr = _build(data, "logreg", {"multi_class": "ovr", "C": 3.16e-3, "max_iter": 100, "pooling": "none", "standardize": False})
    ovr.fit(train.X, train.mask, train.y)
    assert type(ovr.estimator[-1]).__name__ == "OneVsRestClassifier"
    with pytest.raises(ValueError, match="liblinear has no multinomial backend"):
        _build(data, "logreg", {"solver": "liblinear"})
    poly = _build(data, "svm", {"kernel": "poly", "degree": 2, "decision_function_shape": "ovo", "max_iter": 250, "C": 3.16})
    poly.fit(train.X, train.mask, train.y)
    svc = poly.estimator[-1]
    assert (svc.kernel, svc.degree, svc.decision_function_shape, svc.max_iter) == ("poly", 2, "ovo", 250)
