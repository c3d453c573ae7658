"""One model, six properties: the multi-task classifier trains on the real aligned
WLASL-Lex clips (a missing value masks its head's loss), each head's probabilities sum to 1, the
temperature fitted on validation lowers the validation NLL and the held-out ECE is reported; the
one-head form is a registered classifier; a bad config is one clear line."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from aslexp.recognition.models.multitask import (
    DEFAULTS,
    expected_calibration_error,
    fit_multitask,
    fit_temperature,
    nll,
    softmax,
)

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "bench"))
PROPERTIES = ("sign_type", "major_location", "flexion")  # flexion: 15 clips without a value
FAST = {"max_epochs": 8, "patience": 4, "hidden_size": 32}


@pytest.fixture(scope="module")
def data():
    from multitask_compare import load_clips, split_indices

    try:
        clips, codes = load_clips(PROPERTIES)
    except Exception as error:  # noqa: BLE001
        pytest.skip(f"shared data not available: {error}")
    return clips, codes, split_indices(clips.glosses, "phoneme", 0)


def test_the_clips_are_aligned_and_a_missing_value_is_minus_one(data):
    clips, codes, (train, val, test) = data
    assert codes.shape == (len(clips.X), len(PROPERTIES)) and len(clips.X) > 200
    assert (codes[:, 2] < 0).sum() > 0 and (codes[:, :2] >= 0).all()
    assert len(set(train) | set(val) | set(test)) == len(train) + len(val) + len(test)


def test_the_multitask_model_trains_and_its_heads_are_calibrated(data):
    clips, codes, (train, val, test) = data
    model = fit_multitask(clips.X, clips.mask, codes, PROPERTIES, train, val, FAST, seed=0)
    assert [h.name for h in model.heads] == list(PROPERTIES) and 1 <= model.best_epoch <= 8
    assert min(h["train_loss"] for h in model.history[1:]) < model.history[0]["train_loss"]  # it learns
    for calibrated in (False, True):
        for head, proba in zip(model.heads, model.predict_proba(clips.X[test], clips.mask[test], calibrated)):
            assert proba.shape == (len(test), len(head.classes))
            np.testing.assert_allclose(proba.sum(axis=1), 1.0, atol=1e-9)
    for name, row in model.calibration.items():  # fitted on validation: never worse there
        assert row["temperature"] > 0 and row["nll_after"] <= row["nll_before"] + 1e-12, name
    assert any(row["nll_after"] < row["nll_before"] for row in model.calibration.values())
    held_out = model.evaluate(clips.X[test], clips.mask[test], codes[test])
    for name, row in held_out.items():
        assert 0.0 <= row["ece_before"] <= 1.0 and 0.0 <= row["ece_after"] <= 1.0, name
        assert -1.0 <= row["mcc"] <= 1.0 and row["clips"] == int((codes[test, PROPERTIES.index(name)] >= 0).sum())
    print({n: (round(r["ece_before"], 3), round(r["ece_after"], 3)) for n, r in held_out.items()})


def test_a_gloss_head_trains_beside_the_properties_and_is_left_out_after(data):
    clips, codes, (train, val, _) = data
    model = fit_multitask(clips.X, clips.mask, codes[:, :1], PROPERTIES[:1], train, val,
                          {**FAST, "max_epochs": 2, "gloss_head": True}, seed=0, glosses=clips.glosses)
    assert [h.name for h in model.heads] == ["sign_type"] and len(model.net.heads) == 1


def test_temperature_scaling_cools_an_overconfident_model():
    rng = np.random.default_rng(0)
    y = rng.integers(0, 4, 400)
    logits = rng.normal(size=(400, 4))
    logits[np.arange(400), y] += 1.0  # right 50-60% of the time...
    logits *= 6.0  # ...but nearly certain
    t = fit_temperature(logits, y)
    assert t > 2.0 and nll(logits, y, t) < nll(logits, y)
    assert expected_calibration_error(softmax(logits, t), y) < expected_calibration_error(softmax(logits), y)
    assert fit_temperature(logits[:0], y[:0]) == 1.0 and math.isnan(expected_calibration_error(np.zeros((0, 4)), y[:0]))


def test_the_one_head_form_is_a_registered_classifier_with_its_yaml(data):
    from aslexp.recognition.models import build_classifier

    clips, _, _ = data
    config = yaml.safe_load((ROOT / "conf" / "classifier" / "multitask.yaml").read_text())
    assert config["params"] == DEFAULTS
    _, c, t, v, _ = clips.X.shape
    model = build_classifier("multitask", {"hidden_size": 16}, c, t, v, 5, clips.layout, module=config["module"])
    proba = model.predict_proba(clips.X[:7], clips.mask[:7])
    assert proba.shape == (7, 5)
    np.testing.assert_allclose(proba.sum(axis=1), 1.0, atol=1e-5)


@pytest.mark.parametrize("params, message", [
    ({"hiden_size": 32}, "classifier 'multitask': unknown params ['hiden_size']"),
    ({"encoder": "lstm"}, "classifier 'multitask': encoder must be one of ['conv', 'gru'], got 'lstm'"),
    ({"max_epochs": 0}, "classifier 'multitask': max_epochs must be an integer >= 1, got 0"),
])
def test_a_bad_config_is_one_clear_line(data, params, message):
    clips, codes, (train, val, _) = data
    with pytest.raises(ValueError) as caught:
        fit_multitask(clips.X, clips.mask, codes, PROPERTIES, train, val, params)
    text = str(caught.value)
    assert text.startswith(message) and "\n" not in text
