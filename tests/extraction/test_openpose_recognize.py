"""OpenPose `.pose` files through recognition, no MediaPipe needed.

A folder written by pose-format's own OpenPose reader (``load_openpose``) from the shared data's real
MediaPipe Pose clips of another project (their body points under OpenPose's BODY_25 names, in pixels,
visibility as OpenPose's confidence, the hands not found) is read by `aslexp recognize pose=pose_format
pose.path=DIR` with no other pose override: layout=auto takes the header's own layout, its point
names give SL-GCN's 27 points (the config's default subset) and pose-format's confidence is the
visibility channel (the config's default channels). A header whose names are not known is one line
naming the whole fix (pose.subset=all), which then runs.
"""

from __future__ import annotations

import json
import os
import sys

import numpy as np
import pytest
import job_process
from hydra import compose, initialize_config_dir
from pose_format import Pose
from pose_format.numpy import NumPyPoseBody
from pose_format.pose_header import PoseHeader, PoseHeaderComponent, PoseHeaderDimensions
from pose_format.utils.openpose import BODY_POINTS, load_openpose

from aslexp.data.keypoints import open_keypoint_source
from aslexp.data.wlasl_lex import build_wlasl_lex
from aslexp.errors import DataError
from aslexp.jobs._common import CONF_DIR
from aslexp.jobs.recognize import dataset_params
from aslexp.keypoints import SubsetSource, slgcn27

WIDTH, HEIGHT = 640, 480
POSE_DIR = "keypoints/wlasl-mediapipe-pose"
# MediaPipe Pose's index of each OpenPose BODY_25 point it has (the neck and mid-hip are midpoints).
MEDIAPIPE_INDEX = {"Nose": 0, "RShoulder": 12, "RElbow": 14, "RWrist": 16, "LShoulder": 11, "LElbow": 13,
                   "LWrist": 15, "RHip": 24, "RKnee": 26, "RAnkle": 28, "LHip": 23, "LKnee": 25, "LAnkle": 27,
                   "REye": 5, "LEye": 2, "REar": 8, "LEar": 7, "LBigToe": 31, "LHeel": 29, "RBigToe": 32,
                   "RHeel": 30}  # fmt: skip
MIDPOINTS = {"Neck": (11, 12), "MidHip": (23, 24)}


def _openpose_frames(clip: np.ndarray) -> dict:
    """(T, 33, 4) MediaPipe Pose (normalised x, y, z, visibility) -> OpenPose JSON frames: BODY_25
    [x, y, c] in pixels, face and hands not found (zeros, as OpenPose writes them)."""
    frames = {}
    for t, frame in enumerate(clip):
        body = np.zeros((len(BODY_POINTS), 3))
        for k, name in enumerate(BODY_POINTS):
            points = [MEDIAPIPE_INDEX[name]] if name in MEDIAPIPE_INDEX else list(MIDPOINTS.get(name, ()))
            if points:
                x, y = frame[points, :2].mean(axis=0)
                body[k] = [x * WIDTH, y * HEIGHT, frame[points, 3].min()]
        frames[t] = {"people": [{"pose_keypoints_2d": body.ravel().tolist(), "face_keypoints_2d": [0.0] * 210,
                                 "hand_left_keypoints_2d": [0.0] * 63, "hand_right_keypoints_2d": [0.0] * 63}]}
    return frames


def _write(pose: Pose, path) -> None:
    with open(path, "wb") as handle:
        pose.write(handle)


@pytest.fixture(scope="module")
def shared_clips(data_root) -> dict[str, np.ndarray]:
    return {path.stem: np.load(path).reshape(-1, 33, 4) for path in sorted((data_root / POSE_DIR).glob("*.npy"))}


@pytest.fixture(scope="module")
def openpose_folder(shared_clips, tmp_path_factory):
    """<video_id>.pose of the 291 clips, as pose-format's load_openpose writes OpenPose (2 s)."""
    folder = tmp_path_factory.mktemp("openpose")
    for video_id, clip in shared_clips.items():
        _write(load_openpose(_openpose_frames(clip), fps=25, width=WIDTH, height=HEIGHT), folder / f"{video_id}.pose")
    return folder


def _dataset(overrides, data_root):
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        cfg = compose(config_name="recognize", overrides=[*overrides, "data.num_frames=16"])
    return build_wlasl_lex(None, dataset_params(cfg), root=data_root)


def test_an_openpose_folder_reads_with_the_configs_defaults(openpose_folder, shared_clips, data_root):
    dataset = _dataset(["pose=pose_format", f"pose.path={openpose_folder}"], data_root)
    layout = dataset.layout
    assert layout.name.startswith("pose_header_") and layout.name.endswith("_slgcn27")
    assert layout.names == slgcn27.NAMES and dataset.channels == ["x", "y", "visibility"]
    assert dataset.X.shape[1:] == (3, 16, 27, 1) and len(dataset.y) >= 280  # of 291 clips, as pose=mediapipe_pose
    # The 27 points are OpenPose's by name: the nose, shoulders, elbows and wrists are the clip's
    # MediaPipe Pose points (x, y; confidence = visibility); the hands were not found (NaN).
    source = SubsetSource(open_keypoint_source("pose_format", path=openpose_folder), "slgcn27")
    video_id, clip = next(iter(shared_clips.items()))
    got = source.load(video_id)
    body = clip[:, [0, 11, 12, 13, 14, 15, 16]]
    np.testing.assert_allclose(got[:, :7, :2], body[..., :2], atol=1e-5)
    np.testing.assert_allclose(got[:, :7, 2], body[..., 3], atol=1e-6)
    assert np.isnan(got[:, 7:]).all()
    # The advice, the header layout asked for by name: one override, nothing more.
    named = _dataset(["pose=pose_format", f"pose.path={openpose_folder}", "pose.options.layout=header"], data_root)
    np.testing.assert_array_equal(named.X, dataset.X)


@pytest.mark.slow  # a recognize process: 7-15 s on 2 busy cores
def test_aslexp_recognize_runs_on_an_openpose_folder(openpose_folder, data_root, tmp_path):
    """`aslexp recognize pose=pose_format pose.path=DIR` (docs/extraction.md) on a tiny budget."""
    env = {**os.environ, "ASLEXP_DATA_ROOT": str(data_root), "ASLEXP_CACHE_DIR": str(tmp_path / "cache"),
           "MPLBACKEND": "Agg"}  # fmt: skip
    proc = job_process.run([sys.executable, "-m", "aslexp.cli", "recognize", "pose=pose_format",
                           f"pose.path={openpose_folder}", "classifier=logreg", "data.num_frames=16"],
                          cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)  # fmt: skip
    log = proc.stdout + proc.stderr
    assert proc.returncode == 0, log[-3000:]
    assert "(pose.options.layout=auto, read from" in log and "no MediaPipe layout fits" in log
    assert "'openpose'" in log and "slgcn27 mapped by openpose point names" in log
    runs = [json.loads(p.read_text()) for p in (tmp_path / "outputs").rglob("run.json")]
    assert [r["status"] for r in runs] == ["completed"]


def test_a_header_of_unknown_names_says_the_whole_fix(shared_clips, data_root, tmp_path):
    """Points the project has no names for (a tracker's own): the default subset is refused in one
    line that names the fix; with it, the folder runs."""
    points = [f"P{k}" for k in range(33)]
    header = PoseHeader(0.2, PoseHeaderDimensions(WIDTH, HEIGHT),
                        [PoseHeaderComponent("TRACKER", points, [(11, 13), (13, 15), (12, 14), (14, 16), (11, 12)],
                                             [(255, 0, 0)], "XYC")])  # fmt: skip
    for video_id, clip in shared_clips.items():
        data = (clip[:, None, :, :2] * [WIDTH, HEIGHT]).astype(np.float32)
        _write(Pose(header, NumPyPoseBody(25, data, clip[:, None, :, 3].astype(np.float32))),
               tmp_path / f"{video_id}.pose")  # fmt: skip
    with pytest.raises(DataError) as error:
        _dataset(["pose=pose_format", f"pose.path={tmp_path}"], data_root)
    message = str(error.value)
    assert "\n" not in message and "(33 nodes, channels x, y, visibility) has no keypoint subset 'slgcn27'" in message
    assert "set pose.subset=all" in message
    dataset = _dataset(["pose=pose_format", f"pose.path={tmp_path}", "pose.subset=all"], data_root)
    assert dataset.X.shape[1:] == (3, 16, 33, 1) and dataset.channels == ["x", "y", "visibility"]


def test_openpose_135_gives_25_of_sl_gcns_points(shared_clips, tmp_path):
    """pose-format's BODY_135 header (OpenPose's whole-body model): its hands have no root of their
    own (the body wrist is it), so SL-GCN's 27 points are 25 there."""
    from pose_format.utils.openpose_135 import OpenPose_Components

    component = OpenPose_Components[0]
    video_id, clip = next(iter(shared_clips.items()))
    data = np.zeros((len(clip), 1, len(component.points), 2), np.float32)
    confidence = np.zeros((len(clip), 1, len(component.points)), np.float32)
    for name, index in MEDIAPIPE_INDEX.items():
        if name in component.points:
            k = component.points.index(name)
            data[:, 0, k] = clip[:, index, :2] * [WIDTH, HEIGHT]
            confidence[:, 0, k] = clip[:, index, 3]
    _write(Pose(PoseHeader(0.2, PoseHeaderDimensions(WIDTH, HEIGHT), [component]),
                NumPyPoseBody(25, data, confidence)), tmp_path / f"{video_id}.pose")  # fmt: skip
    thesis = SubsetSource(open_keypoint_source("pose_format", path=tmp_path), "slgcn27")
    assert thesis.layout.num_nodes == 25 and "left_hand_root" not in thesis.layout.names
    assert thesis.layout.names[:7] == slgcn27.NAMES[:7]
    got = thesis.load(video_id)
    np.testing.assert_allclose(got[:, :7, :2], clip[:, [0, 11, 12, 13, 14, 15, 16], :2], atol=1e-5)
