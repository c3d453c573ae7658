"""The WLASL-Lex cache is never silently stale (issue 11.4), and a keypoint folder whose every
file is rejected says so (issue 11.7). Real ASL-LEX, WLASL and keypoint files, copied into a
data root of the test's own so that they can be damaged."""

from __future__ import annotations

import logging
import shutil
from pathlib import Path

import numpy as np
import pytest

from aslexp.data.dataset import DataError
from aslexp.keypoints.arrays import MEDIAPIPE_POSE_DIR
from aslexp.data.wlasl_lex import INPUTS, WlaslLexParams, build_or_load

SHARED = Path(__file__).resolve().parents[3] / "shared" / "data"
PARAMS = WlaslLexParams(length=32)


@pytest.fixture()
def data_root(tmp_path: Path) -> Path:
    root = tmp_path / "data"
    (root / "keypoints").mkdir(parents=True)
    for name in ("asl-lex", "wlasl"):
        (root / name).symlink_to(SHARED / name)
    shutil.copytree(SHARED / MEDIAPIPE_POSE_DIR, root / MEDIAPIPE_POSE_DIR)
    return root


def _damage(files: list[Path]) -> None:
    for path in files:  # in place, as a crashed writer or a bad copy leaves them
        path.write_bytes(b"\x93NUMPY garbage" + bytes(64))


def test_damaging_keypoint_files_invalidates_the_cache(data_root, tmp_path, caplog):
    cache = tmp_path / "cache"
    built, folder = build_or_load(cache, PARAMS, root=data_root)
    assert (folder / INPUTS).is_file()
    with caplog.at_level(logging.INFO, logger="aslexp.data.wlasl_lex"):
        reused, same = build_or_load(cache, PARAMS, root=data_root)
    assert same == folder and "reusing WLASL-Lex build" in caplog.text
    np.testing.assert_array_equal(reused.X, built.X)

    files = sorted((data_root / MEDIAPIPE_POSE_DIR).glob("*.npy"))
    used = [f for f in files if f.stem in set(built.video_ids)]
    _damage(used[::2])  # half the clips the build used, as in the report
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="aslexp.data.wlasl_lex"):
        rebuilt, again = build_or_load(cache, PARAMS, root=data_root)
    assert again == folder  # the same cache folder, rebuilt in place
    assert f"WLASL-Lex build {folder} is stale: its input files differ from when it was built " \
           f"({len(used[::2])} changed" in caplog.text
    assert "reusing" not in caplog.text
    assert rebuilt.skipped["bad_keypoint_file"] == len(used[::2])
    assert len(rebuilt.y) < len(built.y)

    (data_root / MEDIAPIPE_POSE_DIR / "extra.npy").write_bytes(files[0].read_bytes())  # a new file
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="aslexp.data.wlasl_lex"):
        build_or_load(cache, PARAMS, root=data_root)
    assert "1 added; e.g." in caplog.text and "extra.npy" in caplog.text


def test_a_folder_whose_every_file_is_rejected_says_so(data_root, tmp_path):
    files = sorted((data_root / MEDIAPIPE_POSE_DIR).glob("*.npy"))
    _damage(files)
    with pytest.raises(DataError) as err:
        build_or_load(tmp_path / "cache", PARAMS, root=data_root)
    text = str(err.value)
    assert text.startswith("keypoint source 'mediapipe_pose_npy': all ")
    assert "keypoint files of the labelled clips were rejected, e.g. " in text
    assert "not a plain .npy array" in text or "cannot" in text or "shape" in text
    assert "no label has" not in text
