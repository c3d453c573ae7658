"""A keypoint .npy whose header lies about its size, or that holds text or objects, is skipped,
counted and named like a truncated one: the reader checks the header against the file's bytes
before it allocates anything. Real keypoint files of the data root, damaged in a copy."""

from __future__ import annotations

import json
import logging
import os
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

import job_process
from aslexp.data.dataset import DataError
from aslexp.data.keypoints import open_keypoint_source
from aslexp.data.wlasl_lex import WlaslLexParams, build_wlasl_lex
from aslexp.keypoints.arrays import MEDIAPIPE_POSE_DIR

PROJECT_ROOT = Path(__file__).resolve().parents[2]


def write_lying_header(path: Path, shape=(10**12, 132)) -> None:
    """A .npy header claiming ``shape`` float64, followed by only 64 bytes of data."""
    with path.open("wb") as handle:
        np.lib.format.write_array_header_1_0(handle, {"descr": "<f8", "fortran_order": False, "shape": shape})
        handle.write(bytes(64))


def write_text_array(path: Path, like: np.ndarray) -> None:
    """The same (T, 132) shape, as strings (a CSV export saved with np.save)."""
    np.save(path, like.astype(str))


@pytest.fixture()
def damaged_root(tmp_path: Path, data_root: Path) -> Path:
    """A data root of the test's own: the real annotations linked, the real keypoints copied."""
    root = tmp_path / "data"
    (root / "keypoints").mkdir(parents=True)
    for name in ("asl-lex", "wlasl"):
        (root / name).symlink_to(data_root / name)
    shutil.copytree(data_root / MEDIAPIPE_POSE_DIR, root / MEDIAPIPE_POSE_DIR)
    return root


@pytest.mark.parametrize("damage, expected", [
    ("lying_header", "its header says shape (1000000000000, 132) of float64 = 1056000000000000 bytes, "
                     "the file holds 64 bytes after the header"),
    ("text", "array of dtype <U"),
    ("objects", "array of dtype object (Python objects); expected numbers"),
])  # fmt: skip
def test_a_lying_header_or_a_non_numeric_array_is_a_data_error_naming_the_file(damaged_root, damage, expected):
    folder = damaged_root / MEDIAPIPE_POSE_DIR
    path = sorted(folder.glob("*.npy"))[0]
    real = np.load(path)
    if damage == "lying_header":
        write_lying_header(path)
    elif damage == "text":
        write_text_array(path, real)
    else:
        np.save(path, np.array([real[0].tolist(), None], dtype=object), allow_pickle=True)
    source = open_keypoint_source("mediapipe_pose_npy", path=folder)
    with pytest.raises(DataError) as error:
        source.load(path.stem)
    assert str(error.value).startswith(f"{path}: ") and expected in str(error.value)
    assert "\n" not in str(error.value)


@pytest.fixture(scope="module")
def whole(data_root):
    """The undamaged build, with the clip length of experiment=debug."""
    return build_wlasl_lex(None, WlaslLexParams(length=32), root=data_root)


def _damage_two_used_files(root: Path, whole) -> tuple[Path, Path]:
    folder = root / MEDIAPIPE_POSE_DIR
    lying, text = (folder / f"{video_id}.npy" for video_id in whole.video_ids[:2])
    write_lying_header(lying)
    write_text_array(text, np.load(text))
    return lying, text


def test_the_dataset_build_skips_counts_and_names_them(damaged_root, whole, caplog):
    lying, text = _damage_two_used_files(damaged_root, whole)
    params = WlaslLexParams(length=32)
    with caplog.at_level(logging.WARNING, logger="aslexp.data.wlasl_lex"):
        dataset = build_wlasl_lex(None, params, root=damaged_root)
    assert dataset.skipped["bad_keypoint_file"] == 2
    assert f"skipping video {lying.stem}: {lying}: not a plain .npy array (Failed to read all data" in caplog.text
    assert f"skipping video {text.stem}: {text}: array of dtype <U" in caplog.text
    assert set(dataset.video_ids) == set(whole.video_ids) - {lying.stem, text.stem}
    with pytest.raises(DataError, match=lying.name):
        build_wlasl_lex(None, params, root=damaged_root, strict=True)


def test_a_recognize_run_goes_on_past_them_and_records_the_count(damaged_root, whole, tmp_path):
    lying, text = _damage_two_used_files(damaged_root, whole)
    run_dir = tmp_path / "run"
    env = dict(os.environ, ASLEXP_DATA_ROOT=str(damaged_root), ASLEXP_CACHE_DIR=str(tmp_path / "cache"),
               MPLBACKEND="Agg")  # fmt: skip
    proc = job_process.run([sys.executable, "-m", "aslexp.cli", "recognize", "experiment=debug", "classifier=majority",
                            f"hydra.run.dir={run_dir}"], cwd=PROJECT_ROOT, env=env, capture_output=True, text=True,
                           timeout=300)  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    log = (run_dir / "recognize.log").read_text()
    assert f"skipping video {lying.stem}: {lying}: not a plain .npy array" in log
    assert f"skipping video {text.stem}: {text}: array of dtype <U" in log
    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert metrics["context"]["skipped"]["bad_keypoint_file"] == 2
    assert metrics["context"]["num_clips"] == len(whole.y) - 2
