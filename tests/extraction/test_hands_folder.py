"""A keypoint format from elsewhere is configuration: a folder of MediaPipe Hands arrays (T, 126),
files named by WLASL video id, made from the project's own extraction of the six real clips,
read by the generic array reader through `conf/pose/*.yaml` into a recognition dataset."""

from __future__ import annotations

import numpy as np
import pytest
import job_process
from hydra import compose, initialize_config_dir

from aslexp.data.wlasl_lex import build_wlasl_lex
from aslexp.errors import DataError
from aslexp.jobs._common import CONF_DIR
from aslexp.jobs.recognize import dataset_params
from aslexp.keypoints import holistic as H

from .conftest import SHORT_RANGES

pytestmark = pytest.mark.usefixtures("worker_env")
GLOSS = {vid: gloss for gloss, clips in SHORT_RANGES.items() for vid in clips}


@pytest.fixture(scope="module")
def hand_folders(wlasl6, tmp_path_factory):
    """hands/<id>.npy (T, 126): both hands, missing = 0 as hand-only pipelines write them;
    right_hand/<id>.npy (T, 63): the right hand alone."""
    out, _ = wlasl6
    base = tmp_path_factory.mktemp("hand_arrays")
    (base / "hands").mkdir()
    (base / "right_hand").mkdir()
    for vid in GLOSS:
        hands = np.nan_to_num(np.load(out / f"{vid}.npy")[:, H.LEFT_HAND_OFFSET :, :3], nan=0.0)
        np.save(base / "hands" / f"{vid}.npy", hands.reshape(len(hands), 126))
        np.save(base / "right_hand" / f"{vid}.npy", hands[:, 21:].reshape(len(hands), 63))
    return base


def _dataset(overrides, data_root):
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        cfg = compose(config_name="recognize", overrides=[*overrides, "split.rare_classes=train_only",
                                                           "data.num_frames=16"])  # fmt: skip
    return build_wlasl_lex(None, dataset_params(cfg), root=data_root)


def test_hands_arrays_through_the_yaml_layout(hand_folders, wlasl6, data_root):
    out, _ = wlasl6
    dataset = _dataset(["pose=mediapipe_hands", f"pose.path={hand_folders / 'hands'}"], data_root)
    assert dataset.layout.name == "mediapipe_hands" and dataset.layout.num_nodes == 42
    assert dataset.channels == ["x", "y", "z"] and dataset.X.shape == (5, 3, 16, 42, 1)
    # 70212 shows no hand in any frame (a title card, then the signer with hands out of view):
    # all-zero arrays, so no observed keypoint: skipped and counted, not silently dropped.
    assert sorted(dataset.video_ids) == sorted(set(GLOSS) - {"70212"}) and dataset.skipped["no_valid_frame"] == 1
    assert dataset.glosses == [GLOSS[v] for v in dataset.video_ids]
    # Zero-filled hands are missing (masked), exactly where the extraction found no hand.
    for row, vid in enumerate(dataset.video_ids):
        seen = np.isfinite(np.load(out / f"{vid}.npy")[:, H.LEFT_HAND_OFFSET :, 0])  # (10, 42)
        np.testing.assert_array_equal(dataset.mask[row, :10], seen)
    assert dataset.mask.any(axis=(1, 2)).all()  # every clip kept has a hand somewhere
    assert len(dataset.splits["train"]) >= 2 and len(dataset.splits["test"]) == 1  # book: 3 clips


def test_a_layout_written_inline_in_yaml(hand_folders, data_root):
    dataset = _dataset(["pose=array_folder", f"pose.path={hand_folders / 'right_hand'}"], data_root)
    assert dataset.layout.name == "one_hand_21" and dataset.layout.names[0] == "wrist"
    assert len(dataset.layout.edges) == 21 and dataset.X.shape[1:] == (3, 16, 21, 1)
    left = _dataset(["pose=mediapipe_hands", f"pose.path={hand_folders / 'hands'}", "pose.subset=right"], data_root)
    np.testing.assert_array_equal(left.mask, dataset.mask)  # the same hand through either route


def test_arrays_that_fit_no_layout_say_so(hand_folders, data_root):
    """The MediaPipe Pose source on hand arrays: one line naming a file and the shape expected,
    not a complaint about too few clips per label."""
    with pytest.raises(DataError) as error:
        _dataset(["pose=mediapipe_pose", f"pose.path={hand_folders / 'hands'}"], data_root)
    message = str(error.value)
    assert "all 6 keypoint files" in message and "shape (10, 126)" in message and "(T, 132)" in message
    assert "\n" not in message and "array_folder" in message


def test_recognize_on_a_folder_of_pose_files(wlasl6, data_root, tmp_path):
    """docs/howto_keypoints.md's .pose route: `aslexp extract ... --format pose`, then
    `aslexp recognize pose=pose_format pose.path=DIR` (here on ten frames of the six clips)."""
    import json
    import os
    import sys

    out, _ = wlasl6
    run_dir = tmp_path / "run"
    proc = job_process.run(
        [sys.executable, "-m", "aslexp.cli", "recognize", "pose=pose_format", f"pose.path={out}",
         "classifier=logreg", "split.rare_classes=train_only", "data.num_frames=16", f"hydra.run.dir={run_dir}"],
        cwd=CONF_DIR.rsplit("/conf", 1)[0], capture_output=True, text=True, timeout=300,
        env={**os.environ, "ASLEXP_CACHE_DIR": str(tmp_path / "cache"), "MPLBACKEND": "Agg"},
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert metrics["context"]["pose"] == "pose_format" and metrics["context"]["num_clips"] == 6
    manifest = json.loads(next((tmp_path / "cache").glob("wlasl_lex-*/manifest.json")).read_text())
    assert manifest["layout"] == "mediapipe_holistic_slgcn27" and manifest["shape"]["V"] == 27


def test_pose_formats_reduced_and_hands_only_files_make_datasets(wlasl6, data_root, tmp_path):
    """The six clips' `.pose` files reduced with pose-format's own reduce_holistic, and cut to the
    hands: `pose=pose_format` with its defaults (subset slgcn27) makes a dataset of each."""
    from pose_format import Pose
    from pose_format.utils.generic import reduce_holistic

    out, _ = wlasl6
    for kind in ("reduced", "hands"):
        (tmp_path / kind).mkdir()
    for vid in GLOSS:
        pose = Pose.read((out / f"{vid}.pose").read_bytes())
        for kind, made in (("reduced", reduce_holistic(pose)),
                           ("hands", pose.get_components(["LEFT_HAND_LANDMARKS", "RIGHT_HAND_LANDMARKS"]))):
            with open(tmp_path / kind / f"{vid}.pose", "wb") as handle:
                made.write(handle)
    reduced = _dataset(["pose=pose_format", f"pose.path={tmp_path / 'reduced'}"], data_root)
    assert reduced.layout.name == "mediapipe_holistic_reduced_slgcn27" and reduced.layout.num_nodes == 26
    assert reduced.channels == ["x", "y", "visibility"] and reduced.X.shape == (6, 3, 16, 26, 1)
    # Hands have no visibility channel: the default channels say what to set, in one line.
    with pytest.raises(DataError) as error:
        _dataset(["pose=pose_format", f"pose.path={tmp_path / 'hands'}"], data_root)
    assert "'mediapipe_hands_slgcn27'" in str(error.value) and "pose.channels=null" in str(error.value)
    hands = _dataset(["pose=pose_format", f"pose.path={tmp_path / 'hands'}", "pose.channels=null"], data_root)
    assert hands.layout.name == "mediapipe_hands_slgcn27" and hands.X.shape == (5, 3, 16, 20, 1)
    assert sorted(hands.video_ids) == sorted(set(GLOSS) - {"70212"})  # 70212 shows no hand
