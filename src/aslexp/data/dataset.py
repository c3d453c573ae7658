"""The recognition dataset as the models see it: arrays, labels and splits, no Hydra."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


class DataError(ValueError):
    """Bad or inconsistent input data; the message names the file, the field and what was expected."""


@dataclass(frozen=True)
class KeypointLayout:
    """A named set of keypoints and the skeleton graph over them.

    ``edges`` are undirected (i, j) index pairs into ``names``; ``center`` is the node the
    ST-GCN spatial partition measures distances from. ``channels`` names the last axis of the
    keypoint arrays (e.g. ``("x", "y", "z", "visibility")``); empty when not known.
    """

    name: str
    names: tuple[str, ...]
    edges: tuple[tuple[int, int], ...]
    center: int = 0
    channels: tuple[str, ...] = ()

    @property
    def num_nodes(self) -> int:
        return len(self.names)


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
