"""Keypoint files not named by WLASL video id, on copies of the project's own
291 real MediaPipe Pose clips renamed in the test:

- ``gloss/``: ``<gloss>_<n>.npy`` (spaces as ``_``: ``thank_you_1.npy``), some in capitals;
- ``youtube/``: ``<YouTube id>.npy`` for the clips whose WLASL url is a YouTube video that no
  other of the 291 clips comes from.

Without a mapping the build stops with one line (count, examples, the naming expected, the
remedy) and `aslexp recognize` exits 2; with ``pose.options.names=gloss`` or a mapping CSV the
dataset builds (the clips and labels of the video-id build) and a run completes.
"""

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

from aslexp.data.naming import youtube_ids
from aslexp.data.wlasl_lex import WlaslLexParams, build_wlasl_lex
from aslexp.errors import DataError

POSE_DIR = "keypoints/wlasl-mediapipe-pose"
ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def named(data_root, wlasl, tmp_path_factory):
    """Folders of renamed copies, and the original video id of every copy."""
    base = tmp_path_factory.mktemp("names")
    source = data_root / POSE_DIR
    ids = sorted(p.stem for p in source.glob("*.npy"))
    by_id = wlasl.by_video_id()
    origin: dict[str, dict[str, str]] = {"gloss": {}, "youtube": {}}
    (base / "gloss").mkdir()
    count: dict[str, int] = {}
    for n, video_id in enumerate(ids):
        gloss = by_id[video_id].gloss
        count[gloss] = count.get(gloss, 0) + 1
        stem = f"{gloss.replace(' ', '_')}_{count[gloss]}"
        stem = stem.upper() if n % 7 == 0 else stem  # matched case-insensitively
        shutil.copy(source / f"{video_id}.npy", base / "gloss" / f"{stem}.npy")
        origin["gloss"][stem] = video_id
    tube = {vid: yt for yt, vids in youtube_ids(wlasl).items() for vid in vids}
    mine = [tube[v] for v in ids if v in tube]
    (base / "youtube").mkdir()
    for video_id in ids:
        if video_id in tube and mine.count(tube[video_id]) == 1:
            shutil.copy(source / f"{video_id}.npy", base / "youtube" / f"{tube[video_id]}.npy")
            origin["youtube"][tube[video_id]] = video_id
    return base, origin


def _build(data_root, path, property="major_location", **options):
    params = WlaslLexParams(property=property, source="mediapipe_pose_npy", source_path=str(path),
                            source_options=options, length=16)  # fmt: skip
    return build_wlasl_lex(None, params, root=data_root)


def _cli(tmp_path, *overrides):
    return job_process.run(
        [sys.executable, "-m", "aslexp.cli", "recognize", "experiment=debug", "classifier=logreg",
         "pose=mediapipe_pose", *overrides, f"hydra.run.dir={tmp_path / 'run'}"],
        cwd=ROOT, capture_output=True, text=True, timeout=600,
        env={**os.environ, "ASLEXP_CACHE_DIR": str(tmp_path / "cache"), "MPLBACKEND": "Agg"},
    )  # fmt: skip


def test_youtube_named_files_exit_2_with_one_line(named, tmp_path):
    base, origin = named
    assert len(origin["youtube"]) == 104
    proc = _cli(tmp_path, f"pose.path={base / 'youtube'}")
    assert proc.returncode == 2, proc.stderr[-3000:]
    line = proc.stderr.strip().splitlines()[-1]
    assert line.startswith(f"aslexp recognize: DataError: keypoint folder {base / 'youtube'}: none of its 104 "
                           "keypoint files is named by a WLASL video id (e.g. ")  # fmt: skip
    first = sorted(origin["youtube"])[0]
    assert f"{first}.npy" in line and "expected <video_id>.npy" in line and "e.g. 63185.npy" in line
    assert "104 of them are YouTube ids of WLASL urls" in line
    assert "pose.options.names=FILE.csv with the header file,video_id" in line


def test_gloss_named_files_say_so(named, data_root):
    base, _ = named
    with pytest.raises(DataError) as error:
        _build(data_root, base / "gloss")
    message = str(error.value)
    assert message.startswith(f"keypoint folder {base / 'gloss'}: none of its 291 keypoint files is named by a "
                              "WLASL video id (e.g. AGAIN_1.npy, ")  # fmt: skip
    assert "285 of them name ASL-LEX 2.0 glosses" in message  # food and sugar are not in ASL-LEX 2.0
    assert "set pose.options.names=gloss" in message and "\n" not in message


def test_gloss_names_build_the_clips_of_the_video_id_build(named, data_root, caplog):
    """Each gloss-named file is its own clip with its gloss's labels: the same clips, glosses and
    labels (and arrays) as the video-id build of the same files."""
    base, origin = named
    caplog.set_level(logging.WARNING)
    by_gloss = _build(data_root, base / "gloss", names="gloss")
    by_id = _build(data_root, data_root / POSE_DIR)
    assert len(by_gloss.video_ids) == len(by_id.video_ids) == 285
    row = {v: i for i, v in enumerate(by_id.video_ids)}
    for i, stem in enumerate(by_gloss.video_ids):
        j = row[origin["gloss"][stem]]
        assert by_gloss.glosses[i] == by_id.glosses[j]
        assert by_gloss.label_names[by_gloss.y[i]] == by_id.label_names[by_id.y[j]]
        np.testing.assert_array_equal(by_gloss.X[i], by_id.X[j])
    assert set(by_gloss.signer_ids) == {-1} and by_gloss.skipped["gloss_not_in_lexicon"] == 6
    warned = [r.getMessage() for r in caplog.records if "gloss-named files name no" in r.getMessage()]
    assert len(warned) == 1 and "6 of its 291 gloss-named files name no ASL-LEX 2.0 gloss" in warned[0]
    assert "-> 'food'" in warned[0] and "-> 'sugar'" in warned[0]  # e.g. food_1.npy -> 'food'
    assert "again" in by_gloss.glosses and "thank you" in by_gloss.glosses  # thank_you_1.npy: WLASL's spelling


def test_a_mapping_csv_and_a_run(named, data_root, tmp_path, caplog):
    base, origin = named
    folder = tmp_path / "youtube"
    shutil.copytree(base / "youtube", folder)
    shutil.copy(data_root / POSE_DIR / "01457.npy", folder / "extra.npy")  # no row: skipped, named
    names = tmp_path / "names.csv"
    names.write_text("file,video_id\n" + "".join(f"{yt}.npy,{vid}\n" for yt, vid in origin["youtube"].items()))
    caplog.set_level(logging.WARNING)
    dataset = _build(data_root, folder, "sign_type", names=str(names))
    assert set(dataset.video_ids) <= set(origin["youtube"].values()) and len(dataset.video_ids) == 100
    assert dataset.skipped["keypoints_not_named"] == 1
    assert any("1 of its 105 files have no row in" in r.getMessage() and "extra.npy" in r.getMessage()
               for r in caplog.records)  # fmt: skip
    proc = _cli(tmp_path, f"pose.path={folder}", f"pose.options.names={names}")
    assert proc.returncode == 0, proc.stderr[-3000:]
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert metrics["context"]["num_clips"] == 100 and metrics["context"]["skipped"]["keypoints_not_named"] == 1


@pytest.mark.parametrize("text, expected", [
    ("name,video_id\na.npy,1\n", "header .*expected the columns file,video_id"),
    ("file,video_id,gloss\na.npy,1,book\n", "one of video_id and gloss"),
    ("file,video_id\na.npy,00335\nb.npy,00335\n", "line 3: video_id 00335 is already given to file a.npy on line 2"),
    ("file,gloss\na.npy,book\na,cake\n", "line 3: file a.npy is already given on line 2"),
    ("file,gloss\na.npy,\n", "line 2: .*expected a file name and a gloss"),
    ("file,video_id\nnot_here.npy,00335\n", "none of its 1 rows names a file of keypoint folder"),
    ("file,video_id\njPn0FQxkdBc.npy,1457\n", "1457\\); expected the video_id .* keep their leading zeros"),
])  # fmt: skip
def test_mapping_mistakes_name_the_line(named, data_root, tmp_path, text, expected):
    base, _ = named
    names = tmp_path / "names.csv"
    names.write_text(text)
    with pytest.raises(DataError, match=expected) as error:
        _build(data_root, base / "youtube", names=str(names))
    assert str(names) in str(error.value) and "\n" not in str(error.value)


def test_a_few_unmatched_files_are_named_not_dropped(data_root, tmp_path, caplog):
    folder = tmp_path / "mixed"
    shutil.copytree(data_root / POSE_DIR, folder)
    shutil.copy(folder / "01457.npy", folder / "whistle.npy")
    caplog.set_level(logging.WARNING)
    dataset = _build(data_root, folder)
    assert dataset.skipped["keypoints_not_in_wlasl"] == 1 and "whistle" not in dataset.video_ids
    lines = [r.getMessage() for r in caplog.records if "match no WLASL video id" in r.getMessage()]
    assert lines == [f"keypoint folder {folder}: 1 of its 292 keypoint files match no WLASL video id and are "
                     "skipped (e.g. whistle.npy); expected <video_id>.npy with the video_id of "
                     "wlasl/WLASL_v0.3.json, e.g. 63185.npy"]  # fmt: skip


def test_an_empty_folder_says_what_it_expected(data_root, tmp_path):
    with pytest.raises(DataError, match=f"keypoint folder {tmp_path}: no keypoint files found; expected "
                                        r"<video_id>.npy with the video_id of wlasl/WLASL_v0.3.json"):  # fmt: skip
        _build(data_root, tmp_path)
