import numpy as np
import pytest

from aslexp.data.dataset import DataError
from aslexp.data.preprocess import fit_length, preprocess_clips

CHANNELS = ["x", "y", "visibility"]


def _clip(frames, nodes=4, seed=0):
    rng = np.random.default_rng(seed)
    clip = rng.uniform(0.2, 0.8, size=(frames, nodes, 3)).astype(np.float32)
    clip[..., 0] *= 2.0  # x spans twice the range of y
    return clip


def test_fit_length():
    clip = np.arange(3, dtype=np.float32)[:, None, None]
    assert fit_length(clip, 7, "loop").ravel().tolist() == [0, 1, 2, 0, 1, 2, 0]
    padded = fit_length(clip, 5, "zero").ravel()
    assert padded[:3].tolist() == [0, 1, 2] and np.isnan(padded[3:]).all()
    assert fit_length(clip, 2).ravel().tolist() == [0, 1]
    with pytest.raises(DataError, match="padding"):
        fit_length(clip, 5, "mirror")


def test_normalisation_keeps_aspect_and_range():
    clip = _clip(20)
    out = preprocess_clips([clip], CHANNELS, length=20)
    x, y, score = out.X[0, 0, ..., 0], out.X[0, 1, ..., 0], out.X[0, 2, ..., 0]
    assert out.X.shape == (1, 3, 20, 4, 1) and out.X.dtype == np.float32
    assert np.isclose(x.max(), 1) and np.isclose(x.min(), -1)  # widest channel spans [-1, 1]
    assert y.max() <= 1 and y.min() >= -1 and (y.max() - y.min()) < 1.5
    np.testing.assert_allclose(np.ptp(x) / np.ptp(y), np.ptp(clip[..., 0]) / np.ptp(clip[..., 1]), rtol=1e-5)
    np.testing.assert_array_equal(score, clip[..., 2])  # score untouched


def test_missing_nan_inf_and_empty_clips():
    clip = _clip(10)
    clip[2] = np.nan  # a frame without detection
    clip[3, 1, 0] = np.inf
    empty = np.zeros((0, 4, 3), np.float32)
    all_missing = np.full((5, 4, 3), np.nan, np.float32)
    out = preprocess_clips([clip, empty, all_missing, _clip(200)], CHANNELS, length=16, padding="zero")
    assert out.kept.tolist() == [0, 3] and out.skipped_no_valid_frame == [1, 2]
    assert out.stats["inf_values"] == 1 and out.stats["frames_without_keypoints_in"] == 1 + 5
    mask = out.mask[0]
    assert not mask[2].any() and not mask[3, 1] and mask[3, 0]
    assert not mask[10:].any() and mask[:2].all()  # zero padding is missing
    assert (out.X[0][:, ~mask] == 0).all() and np.isfinite(out.X).all()
    assert np.abs(out.X[:, :2]).max() <= 1.0
    with pytest.raises(DataError, match="channels"):
        preprocess_clips([np.zeros((3, 4, 2))], CHANNELS)
