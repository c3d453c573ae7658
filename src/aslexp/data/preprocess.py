"""From variable-length keypoint clips with NaN to fixed-length, normalised model inputs.

Steps per clip (T_i, V, C) -> (C, T, V):
1. Missing: a keypoint (t, v) is missing when any of its channels is NaN or +-inf. Non-finite
   values are counted (``nonfinite_values``; NaN is how sources mark "not detected").
2. Length: ``length`` frames (default 150). Longer clips keep their first ``length`` frames;
   shorter ones are looped (``padding='loop'``: frame t = clip[t mod T_i]) or padded with missing
   frames (``padding='zero'``).
3. Normalisation, per clip, on the observed keypoints of the fitted clip: each spatial channel
   (every channel but the score channels ``SCORE_CHANNELS``) is centred on the midpoint of its
   min and max, and all spatial channels are divided by the same number, half the largest
   min-max range among them, so the aspect ratio is kept and values lie in [-1, 1]. Score /
   visibility channels are left as they are (in [0, 1]).
4. Missing keypoints are set to 0 and ``mask`` is False there.
Clips without a single observed keypoint (including empty clips) are skipped and counted.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Iterable, Sequence

import numpy as np

from aslexp.data.dataset import DataError

log = logging.getLogger(__name__)

SCORE_CHANNELS = frozenset({"visibility", "score", "confidence", "presence"})
PADDINGS = ("loop", "zero")


def fit_length(clip: np.ndarray, length: int, padding: str = "loop") -> np.ndarray:
    """(T_i, V, C) -> (length, V, C): truncate, or loop / pad with NaN frames."""
    if padding not in PADDINGS:
        raise DataError(f"unknown padding {padding!r}; expected one of {PADDINGS}")
    if length < 1:
        raise DataError(f"length must be >= 1, got {length}")
    frames = len(clip)
    if frames == 0:
        raise DataError("cannot fit an empty clip")
    if frames >= length:
        return clip[:length]
    if padding == "loop":
        return clip[np.arange(length) % frames]
    pad = np.full((length - frames, *clip.shape[1:]), np.nan, dtype=clip.dtype)
    return np.concatenate([clip, pad])


def normalise_clip(clip: np.ndarray, observed: np.ndarray, channels: Sequence[str]) -> np.ndarray:
    """Centre and scale the spatial channels of a (T, V, C) clip (rule in the module docstring).

    ``observed`` (T, V) selects the keypoints used for the statistics; other entries are left to
    the caller. Returns a new float32 array.
    """
    out = np.array(clip, dtype=np.float32)
    spatial = [i for i, name in enumerate(channels) if name not in SCORE_CHANNELS]
    if not spatial or not observed.any():
        return out
    values = out[observed][:, spatial]  # (K, S)
    low, high = values.min(axis=0), values.max(axis=0)
    half_range = float((high - low).max()) / 2.0
    scale = half_range if half_range > 0 else 1.0
    # clip: float32 rounding can land a hair outside [-1, 1]
    out[..., spatial] = np.clip((out[..., spatial] - (low + high) / 2.0) / scale, -1.0, 1.0)
    return out


@dataclass
class Preprocessed:
    X: np.ndarray  # (N, C, T, V, 1) float32
    mask: np.ndarray  # (N, T, V) bool
    kept: np.ndarray  # (N,) indices of the input clips that were kept
    skipped_no_valid_frame: list[int] = field(default_factory=list)
    stats: dict[str, int] = field(default_factory=dict)


def preprocess_clips(
    clips: Iterable[np.ndarray],
    channels: Sequence[str],
    length: int = 150,
    padding: str = "loop",
) -> Preprocessed:
    """Turn (T_i, V, C) clips into ``Preprocessed`` arrays (see the module docstring)."""
    channels = list(channels)
    inputs, masks, kept, skipped = [], [], [], []
    stats = dict(nonfinite_values=0, inf_values=0, missing_keypoints_in=0, frames_in=0,
                 frames_without_keypoints_in=0)  # fmt: skip
    for index, clip in enumerate(clips):
        clip = np.asarray(clip, dtype=np.float32)
        if clip.ndim != 3 or clip.shape[-1] != len(channels):
            raise DataError(f"clip {index}: shape {clip.shape}, expected (T, V, {len(channels)}) "
                            f"for channels {channels}")  # fmt: skip
        finite = np.isfinite(clip)
        observed = finite.all(axis=-1)  # (T, V)
        stats["nonfinite_values"] += int((~finite).sum())
        stats["inf_values"] += int(np.isinf(clip).sum())
        stats["missing_keypoints_in"] += int((~observed).sum())
        stats["frames_in"] += len(clip)
        stats["frames_without_keypoints_in"] += int((~observed.any(axis=1)).sum())
        if not observed.any():
            skipped.append(index)
            continue
        clip = np.where(observed[..., None], clip, np.nan)
        fitted = fit_length(clip, length, padding)
        fitted_observed = np.isfinite(fitted).all(axis=-1)
        normalised = normalise_clip(fitted, fitted_observed, channels)
        normalised[~fitted_observed] = 0.0
        inputs.append(normalised.transpose(2, 0, 1)[..., None])  # C, T, V, 1
        masks.append(fitted_observed)
        kept.append(index)
    if skipped:
        log.warning("skipped %d clip(s) with no observed keypoint at all (inputs %s)",
                    len(skipped), skipped[:20])  # fmt: skip
    if stats["inf_values"]:
        log.warning("%d infinite keypoint value(s) treated as missing", stats["inf_values"])
    num_channels = len(channels)
    X = (np.stack(inputs) if inputs else np.zeros((0, num_channels, length, 0, 1), np.float32))
    mask = np.stack(masks) if masks else np.zeros((0, length, 0), dtype=bool)
    return Preprocessed(X=X.astype(np.float32, copy=False), mask=mask,
                        kept=np.asarray(kept, dtype=np.int64), skipped_no_valid_frame=skipped,
                        stats=stats)  # fmt: skip
