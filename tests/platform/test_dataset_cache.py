"""The WLASL-Lex cache is never silently stale, and a keypoint folder whose every
file is rejected says so. Real ASL-LEX, WLASL and keypoint files, copied into a
data root of the test's own so that they can be damaged."""

from __future__ import annotations

import hashlib
import json
import logging
import os
import shutil
import subprocess
import sys
import time
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


def test_an_empty_or_truncated_keypoint_file_is_skipped_counted_and_named(data_root, tmp_path, caplog):
    """A 0-byte .npy (a crashed copy) is a damaged file like the others: skipped, counted, named."""
    files = sorted((data_root / MEDIAPIPE_POSE_DIR).glob("*.npy"))
    whole, _ = build_or_load(tmp_path / "before", PARAMS, root=data_root)
    used = [f for f in files if f.stem in set(whole.video_ids)]
    empty, cut = used[0], used[1]
    empty.write_bytes(b"")
    cut.write_bytes(cut.read_bytes()[:200])  # header and a few values: the write stopped there
    with caplog.at_level(logging.WARNING, logger="aslexp.data.wlasl_lex"):
        dataset, _ = build_or_load(tmp_path / "after", PARAMS, root=data_root)
    assert dataset.skipped["bad_keypoint_file"] == 2
    assert f"skipping video {empty.stem}: {empty}: empty file (0 bytes), not a .npy array" in caplog.text
    assert f"skipping video {cut.stem}: {cut}: not a plain .npy array (Failed to read all data" in caplog.text
    assert set(dataset.video_ids) == set(whole.video_ids) - {empty.stem, cut.stem}


def test_a_rewrite_that_keeps_size_and_mtime_rebuilds_the_cache(data_root, tmp_path, caplog):
    """The cache compares the inputs' content (SHA-256), not their size and mtime."""
    cache = tmp_path / "cache"
    built, folder = build_or_load(cache, PARAMS, root=data_root)
    path = next(f for f in sorted((data_root / MEDIAPIPE_POSE_DIR).glob("*.npy")) if f.stem == built.video_ids[0])
    before = path.stat()
    array = np.load(path)
    np.save(path, array[::-1].copy())  # other bytes, the same size: the clip played backwards
    os.utime(path, ns=(before.st_atime_ns, before.st_mtime_ns))  # as `cp -p` or a restore leaves it
    after = path.stat()
    assert (after.st_size, after.st_mtime_ns) == (before.st_size, before.st_mtime_ns)
    with caplog.at_level(logging.INFO, logger="aslexp.data.wlasl_lex"):
        rebuilt, again = build_or_load(cache, PARAMS, root=data_root)
    assert again == folder and "reusing" not in caplog.text
    assert f"is stale: its input files differ from when it was built (1 changed; e.g. {path})" in caplog.text
    row = rebuilt.video_ids.index(path.stem)
    assert not np.array_equal(rebuilt.X[row], built.X[built.video_ids.index(path.stem)])
    caplog.clear()
    os.utime(path)  # a touch changes no byte: the build stays
    with caplog.at_level(logging.INFO, logger="aslexp.data.wlasl_lex"):
        build_or_load(cache, PARAMS, root=data_root)
    assert "reusing WLASL-Lex build" in caplog.text


_REBUILDER = """
import hashlib, json, sys, time
from pathlib import Path
from aslexp.data.wlasl_lex import WlaslLexParams, build_or_load
cache, root, ready, go = map(Path, sys.argv[1:5])
ready.touch()
while not go.exists():  # both processes start the lookup at the same instant
    time.sleep(0.001)
dataset, folder = build_or_load(cache, WlaslLexParams(length=32), root=root)
print(json.dumps({"folder": str(folder), "clips": len(dataset.y),
                  "X": hashlib.sha256(dataset.X.tobytes()).hexdigest()}))
"""


def test_two_processes_rebuilding_one_stale_cache_at_once_both_succeed(data_root, tmp_path, caplog):
    """The rebuild of a stale build goes to a folder beside it, renamed into place in
    one step (a build that appeared meanwhile wins): no process ever reads half a build. Five
    rounds of two real processes started at the same instant on a stale build."""
    cache = tmp_path / "cache"
    built, folder = build_or_load(cache, PARAMS, root=data_root)
    path = next(f for f in sorted((data_root / MEDIAPIPE_POSE_DIR).glob("*.npy")) if f.stem == built.video_ids[0])
    versions = [np.load(path), np.load(path)[::-1].copy()]
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    for round_ in range(5):
        np.save(path, versions[(round_ + 1) % 2])  # the build is stale now
        flags = tmp_path / f"round{round_}"
        flags.mkdir()
        procs = [subprocess.Popen([sys.executable, "-c", _REBUILDER, str(cache), str(data_root),
                                   str(flags / f"ready{i}"), str(flags / "go")],
                                  stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
                 for i in range(2)]
        deadline = time.monotonic() + 60
        while not all((flags / f"ready{i}").exists() for i in range(2)) and time.monotonic() < deadline:
            time.sleep(0.005)
        (flags / "go").touch()
        results = []
        for proc in procs:
            out, err = proc.communicate(timeout=120)
            assert proc.returncode == 0, f"round {round_}: {err[-3000:]}"
            results.append(json.loads(out.strip().splitlines()[-1]))
        assert results[0] == results[1] and results[0]["folder"] == str(folder), round_
        assert [p.name for p in cache.iterdir()] == [folder.name]  # no half build, nothing left aside
        caplog.clear()
        with caplog.at_level(logging.INFO, logger="aslexp.data.wlasl_lex"):
            reread, _ = build_or_load(cache, PARAMS, root=data_root)  # what they left is fresh
        assert "reusing WLASL-Lex build" in caplog.text
        assert hashlib.sha256(reread.X.tobytes()).hexdigest() == results[0]["X"]
