"""Shared by the recognition tests: a small real recognition data set built here from the shared MediaPipe keypoints and WLASL
glosses (independent of aslexp.data, which is written in parallel)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from aslexp.data.dataset import KeypointLayout, RecognitionDataset

DATA_ROOT = Path(os.environ.get("ASLEXP_DATA_ROOT", Path(__file__).resolve().parents[3] / "shared" / "data"))
KEYPOINTS = DATA_ROOT / "keypoints" / "wlasl-mediapipe-pose"
WLASL = DATA_ROOT / "wlasl" / "WLASL_v0.3.json"

NUM_FRAMES = 24
GLOSSES = ("drink", "go", "hot", "like")  # the four most frequent glosses among the 291 clips

# MediaPipe Pose connections (mediapipe.solutions.pose.POSE_CONNECTIONS). The face and mouth
# are not connected to the body in this graph, so from the left shoulder they are unreachable.
POSE_EDGES = (
    (0, 1), (1, 2), (2, 3), (3, 7), (0, 4), (4, 5), (5, 6), (6, 8), (9, 10), (11, 12), (11, 13),
    (13, 15), (15, 17), (15, 19), (15, 21), (17, 19), (12, 14), (14, 16), (16, 18), (16, 20),
    (16, 22), (18, 20), (11, 23), (12, 24), (23, 24), (23, 25), (24, 26), (25, 27), (26, 28),
    (27, 29), (28, 30), (29, 31), (30, 32), (27, 31), (28, 32),
)
POSE_LAYOUT = KeypointLayout(
    name="mediapipe-pose", names=tuple(f"pose_{i}" for i in range(33)), edges=POSE_EDGES, center=11
)


def _fixed_length(frames: np.ndarray, length: int) -> np.ndarray:
    """Truncate, or loop a short clip, to ``length`` frames."""
    return np.resize(frames, (length,) + frames.shape[1:]) if len(frames) < length else frames[:length]


def load_gloss_dataset(glosses=GLOSSES, num_frames: int = NUM_FRAMES) -> RecognitionDataset:
    if not KEYPOINTS.is_dir() or not WLASL.is_file():
        pytest.skip(f"shared data not found under {DATA_ROOT}")
    video_gloss = {}
    for entry in json.loads(WLASL.read_text()):
        for instance in entry["instances"]:
            video_gloss[instance["video_id"]] = (entry["gloss"], instance["signer_id"])
    video_ids, X, masks, labels, signers = [], [], [], [], []
    for path in sorted(KEYPOINTS.glob("*.npy")):
        gloss, signer = video_gloss.get(path.stem, (None, None))
        if gloss not in glosses:
            continue
        raw = _fixed_length(np.load(path), num_frames).reshape(num_frames, 33, 4)
        observed = np.any(raw != 0, axis=2)  # (T, V); all-zero rows are missing frames
        xyz = np.clip(np.stack([2 * raw[..., 0] - 1, 2 * raw[..., 1] - 1, raw[..., 2]]), -1, 1)  # (C, T, V)
        X.append((xyz * observed).astype(np.float32)[..., None])
        masks.append(observed)
        labels.append(glosses.index(gloss))
        video_ids.append(path.stem)
        signers.append(signer)
    y = np.array(labels, dtype=np.int64)
    # Per class, in file order: 60% train, 20% val, 20% test.
    train, val, test = [], [], []
    for label in range(len(glosses)):
        members = np.flatnonzero(y == label)
        n_train, n_val = int(round(0.6 * len(members))), int(round(0.2 * len(members)))
        train += members[:n_train].tolist()
        val += members[n_train : n_train + n_val].tolist()
        test += members[n_train + n_val :].tolist()
    splits = {"train": np.array(train), "val": np.array(val), "test": np.array(test), "train+val": np.array(train + val)}
    return RecognitionDataset(
        property="gloss", label_names=list(glosses), X=np.stack(X), mask=np.stack(masks), y=y,
        video_ids=video_ids, glosses=[glosses[i] for i in y], signer_ids=signers, layout=POSE_LAYOUT,
        channels=["x", "y", "z"], splits=splits,
    )


FAST_TRAINER = {"max_epochs": 2, "patience": 5, "batch_size": 16, "num_threads": 1, "lr": 3e-3}

TINY_PARAMS = {
    "majority": {},
    "stratified": {},
    "logreg": {"max_iter": 300},
    "svm": {"pooling": "mean_std"},
    "rf": {"n_estimators": 20, "n_jobs": 1},
    "hgb": {"max_iter": 10},
    "mlp": {"hidden_sizes": [32]},
    "lstm": {"hidden_size": 16, "num_layers": 1},
    "gru": {"hidden_size": 16, "num_layers": 2},
    "stgcn": {"channels": [8, 16], "temporal_kernel": 3, "adaptive": True},
    "slgcn": {"channels": [16, 32], "groups": 8, "block_size": 5, "drop_from_block": 1},
    "cnn3d": {"channels": [4, 8], "heatmap_size": 12, "frame_stride": 2},
}


def load_lex_dataset(prop: str = "sign_type", lexicon: str = "asllex2", num_frames: int = 24) -> RecognitionDataset:
    """A real WLASL-Lex build through the data layer (MediaPipe Pose upper body, x/y/visibility)."""
    from aslexp.data.wlasl_lex import WlaslLexParams, build_wlasl_lex

    if not KEYPOINTS.is_dir() or not WLASL.is_file():
        pytest.skip(f"shared data not found under {DATA_ROOT}")
    params = WlaslLexParams(lexicon=lexicon, property=prop, subset="upper_body", channels=("x", "y", "visibility"),
                            split="phoneme", length=num_frames)
    return build_wlasl_lex(None, params, root=DATA_ROOT)
