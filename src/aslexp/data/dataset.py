"""The recognition dataset as the models see it: arrays, labels and splits, no Hydra."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

# The dataset carries a keypoint layout; both names are defined lower (keypoints/, errors.py).
from aslexp.errors import DataError  # noqa: F401
from aslexp.keypoints.layout import KeypointLayout


@dataclass
class RecognitionDataset:
    """One phonological property on one keypoint source, split for training.

    X:      (N, C, T, V, 1) float32, coordinates in [-1, 1]; missing keypoints are 0 and
            ``mask`` is False there.
    mask:   (N, T, V) bool, True where the keypoint was observed.
    y:      (N,) int64 class ids into ``label_names``.
    splits: index arrays: 'train', 'val', 'test', 'train+val'; for cv5 also
            'folds' = [(train_idx, val_idx), ...] over 'train+val'.
    """

    property: str
    label_names: list[str]
    X: np.ndarray
    mask: np.ndarray
    y: np.ndarray
    video_ids: list[str]
    glosses: list[str]
    signer_ids: list[int]
    layout: KeypointLayout
    channels: list[str]
    splits: dict[str, object] = field(default_factory=dict)
    skipped: dict[str, int] = field(default_factory=dict)

    @property
    def num_classes(self) -> int:
        return len(self.label_names)

    def subset(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        idx = np.asarray(self.splits[name])
        return self.X[idx], self.y[idx]
