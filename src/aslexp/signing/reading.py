"""A performance read back by the recognition wing (docs/signing.md, "Read back"): each stage's
keypoints (the retargeted reference, the controller alone, the policy) and the source clip's own,
read by the fold models that never saw the clip's gloss (:mod:`aslexp.recognition.read_back`), each
property's reading and the lexicon rank of the true gloss beside the person's.

The stages' keypoints are aslexp's Holistic points (T, 75, 4) in the source's image frame; the
models read MediaPipe Pose's 33 (the keypoint source's layout), so the first 33 go to the reader,
a point the body does not make (NaN) as the reader's missing point (zeros), a made point's
visibility 1. The models a run reads with (``signing.read_back.overrides`` in conf/imitate.yaml) read
positions only: models fitted on the tracker's visibility too read the person's own clip with its
visibility set to 1 at a median lookup rank of 64 instead of 46, a loss that is no signer's.
"""

from __future__ import annotations

import functools

import logging
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from aslexp.keypoints import holistic as H

log = logging.getLogger(__name__)

SOURCE_STAGE = "source"  # the person's own clip: the bar every stage is read against


def pose_array(keypoints: np.ndarray) -> np.ndarray:
    """(T, 75, 4) Holistic image keypoints -> (T, 33, 4) MediaPipe Pose, an unmade point all zeros
    (the reader's missing point)."""
    pose = np.array(np.asarray(keypoints, dtype=np.float32)[:, : H.NUM_POSE], copy=True)
    pose[~np.isfinite(pose).all(axis=-1)] = 0.0
    return pose


def gloss_of_source(report: Mapping[str, Any] | None, source_path: str | Path, data_root: str | Path) -> str | None:
    """The gloss a source clip signs: its motion report's (``pose_array.gloss``, from ``--wlasl``),
    else WLASL's entry for the file's video id; None when neither knows."""
    record = (report or {}).get("pose_array") or {}
    if record.get("gloss"):
        return str(record["gloss"])
    from aslexp.data.root import resolve_data_root
    from aslexp.data.wlasl import WLASL_JSON

    path = resolve_data_root(data_root) / WLASL_JSON
    try:
        glosses = _wlasl_glosses(str(path), path.stat().st_mtime_ns)
    except (OSError, ValueError):
        return None
    return glosses.get(Path(source_path).stem)


@functools.lru_cache(maxsize=4)
def _wlasl_glosses(path: str, mtime_ns: int) -> dict[str, str]:
    """WLASL's video id -> gloss, read once per file version (a clip loop asks per clip: 1.4 s a read)."""
    from aslexp.data.wlasl import load_wlasl

    return {vid: str(instance.gloss) for vid, instance in load_wlasl(path=path).by_video_id().items()}


def compact(record: Mapping[str, Any]) -> dict[str, Any]:
    """What a run folder keeps of one read-back: each property's reading, the lexicon rank, the fold."""
    return {
        "properties": {p: {k: v[k] for k in ("predicted", "asllex", "agrees", "probability", "majority")}
                       for p, v in record["properties"].items()},
        "lexicon_rank": record["lexicon_rank"], "lexicon_size": record["lexicon_size"],
        "ranks": record["ranks"], "fold": record["fold"], "gloss_in_folds": record["gloss_in_folds"],
    }


def source_input(source_file: str | Path) -> Path | np.ndarray:
    """What the readers take of the person's clip: the file, or a video's Holistic array (an
    extraction's ``<id>.npy``, (T, 75, 4)) cut to its 33 Pose points (:func:`pose_array`)."""
    path = Path(source_file)
    if path.suffix == ".npy":
        array = np.load(path, mmap_mode="r", allow_pickle=False)
        if array.ndim == 3 and array.shape[1] == H.NUM_NODES:
            return pose_array(np.asarray(array))
    return path


def read_back_stages(models, stage_keypoints: Mapping[str, np.ndarray], source_file: str | Path,
                     gloss: str) -> dict[str, Any]:
    """Every stage's keypoints and the source's own clip read back by the fold that held ``gloss``
    out: ``{"gloss", "fold_note", "stages": {name: compact record}}`` (the source under ``source``)."""
    from aslexp.recognition.read_back import read_back_many

    names = [SOURCE_STAGE, *stage_keypoints]
    items = [(source_input(source_file), gloss), *((pose_array(k), gloss) for k in stage_keypoints.values())]
    records = read_back_many(items, models, origins=[f"{name} ({gloss})" for name in names])
    return {"gloss": gloss, "entry_id": records[0]["entry_id"], "fold_note": records[0]["fold_note"],
            "stages": {name: compact(r) for name, r in zip(names, records)}}


_MODELS: dict[tuple[str, ...], Any] = {}


def models_for(overrides: tuple[str, ...] = ()):
    """The read-back's fold models (conf/read_back.yaml with ``overrides``): read from the model
    cache, fitted where it has none (minutes, once), kept for this process (a multirun's jobs
    share them)."""
    if overrides not in _MODELS:
        from aslexp.recognition.read_back import fit_fold_models, load_setup

        _MODELS[overrides] = fit_fold_models(load_setup(list(overrides)))
    return _MODELS[overrides]
