"""A folder of `.pose` files with a damaged one: the folder's layout is read from
the first readable file and said in the log, and the damaged file is skipped with a warning, as a
damaged `.npy` is."""

from __future__ import annotations

import logging

import numpy as np
import pytest

from aslexp.errors import DataError
from aslexp.keypoints.posefile import PoseFormatSource, write_holistic_pose


def _clip(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    keypoints = rng.uniform(0.2, 0.8, size=(12, 75, 4)).astype(np.float32)
    keypoints[..., 3] = 1.0  # seen
    return keypoints


def test_a_damaged_first_file_neither_chooses_the_layout_nor_stops_the_folder(tmp_path, caplog):
    (tmp_path / "00001.pose").write_bytes(b"not a pose file at all")  # sorted first
    for name, seed in (("00002", 0), ("00003", 1)):
        write_holistic_pose(tmp_path / f"{name}.pose", _clip(seed), 25.0, 480, 320)
    source = PoseFormatSource(tmp_path)
    with caplog.at_level(logging.INFO):
        layout = source.layout
    said = [r.getMessage() for r in caplog.records]
    assert any("00001.pose: not a readable .pose file" in m for m in said)
    assert any(f".pose layout {layout.name} (pose.options.layout=auto, read from 00002.pose)" in m for m in said)
    assert source.load("00003").shape[0] == 12
    with pytest.raises(DataError, match="00001.pose: not a readable .pose file"):
        source.load("00001")  # the dataset build skips it with this line (bad_keypoint_file)


def test_a_folder_of_damaged_files_is_one_line(tmp_path):
    (tmp_path / "a.pose").write_bytes(b"")
    with pytest.raises(DataError, match="none of its 1 .pose files is readable"):
        PoseFormatSource(tmp_path).layout
