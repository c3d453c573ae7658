"""`.pose` files (pose-format): the project's own MediaPipe output written as `.pose`, read back
with pose-format's own reader and with the `pose_format` keypoint source, retargeted from a
`.pose`; a foreign layout is read from its own header."""

from __future__ import annotations

import logging

import numpy as np
import pytest
from pose_format import Pose
from pose_format.numpy import NumPyPoseBody
from pose_format.pose_header import PoseHeader, PoseHeaderComponent, PoseHeaderDimensions
from pose_format.utils.generic import detect_known_pose_format

from aslexp.data.keypoints import open_keypoint_source
from aslexp.errors import DataError
from aslexp.keypoints import MEDIAPIPE_HOLISTIC, SubsetSource
from aslexp.keypoints.posefile import HAND_POINTS, POSE_POINTS, write_holistic_pose
from aslexp.pose import retarget as R
from aslexp.pose.extract import read_status, write_pose_files
from aslexp.sim.motion import load_motion

from .conftest import CLIP

pytestmark = pytest.mark.usefixtures("worker_env")

COMPONENTS = ["POSE_LANDMARKS", "LEFT_HAND_LANDMARKS", "RIGHT_HAND_LANDMARKS", "POSE_WORLD_LANDMARKS",
              "LEFT_HAND_WORLD_LANDMARKS", "RIGHT_HAND_WORLD_LANDMARKS"]  # fmt: skip


@pytest.fixture(scope="module")
def pose_dir(extracted, tmp_path_factory):
    """The session's extraction of the whistle clip, converted to <dir>/63185.pose."""
    out, _, _ = extracted
    folder = tmp_path_factory.mktemp("pose")
    written = write_pose_files(out, [CLIP, "nobody"])
    assert written["nobody"].startswith("failed")
    (folder / f"{CLIP}.pose").write_bytes((out / f"{CLIP}.pose").read_bytes())
    return folder


def test_pose_formats_own_reader_reads_it(extracted, pose_dir):
    out, _, _ = extracted
    image = np.load(out / f"{CLIP}.npy")
    pose = Pose.read((pose_dir / f"{CLIP}.pose").read_bytes())
    header = pose.header
    assert [c.name for c in header.components] == COMPONENTS
    assert [len(c.points) for c in header.components] == [33, 21, 21, 33, 21, 21]
    assert header.components[0].points == list(POSE_POINTS) and header.components[1].points == list(HAND_POINTS)
    assert all(c.format == "XYZC" for c in header.components)
    assert (header.dimensions.width, header.dimensions.height) == (480, 320)
    assert detect_known_pose_format(pose) == "holistic"
    assert pose.body.data.shape == (57, 1, 150, 3) and pose.body.fps == 25.0
    # Pixels = normalised coordinates x width / height; confidence = visibility; the left hand
    # (never seen in this clip) is masked, the right hand never.
    np.testing.assert_allclose(pose.body.data[:, 0, :33, 0] / 480, image[:, :33, 0], atol=1e-5)
    np.testing.assert_allclose(pose.body.data[:, 0, :33, 1] / 320, image[:, :33, 1], atol=1e-5)
    np.testing.assert_allclose(pose.body.confidence[:, 0, :33], image[:, :33, 3], atol=1e-6)
    left = np.isfinite(image[:, 33:54]).all(axis=(1, 2))  # none, or a few frames on some CPUs
    assert pose.body.data.mask[~left, 0, 33:54].all() and not pose.body.data.mask[left, 0, 33:54].any()
    assert not pose.body.data.mask[:, 0, 54:75].any()
    # pose-format's own operations work on it: normalise by the shoulders.
    info = header.normalization_info(p1=("POSE_LANDMARKS", "RIGHT_SHOULDER"), p2=("POSE_LANDMARKS", "LEFT_SHOULDER"))
    normalised = pose.normalize(info)
    shoulders = normalised.body.data[:, 0, 11] - normalised.body.data[:, 0, 12]
    assert np.mean(np.linalg.norm(shoulders, axis=-1)) == pytest.approx(1.0, abs=1e-3)  # mean width = 1


def test_pose_format_source_gives_back_the_arrays(extracted, pose_dir):
    out, _, _ = extracted
    source = open_keypoint_source("pose_format", path=pose_dir)
    assert source.layout == MEDIAPIPE_HOLISTIC and source.available() == {CLIP}
    clip = source.load(CLIP)
    image = np.load(out / f"{CLIP}.npy")
    assert clip.shape == image.shape == (57, 75, 4)
    np.testing.assert_array_equal(np.isnan(clip), np.isnan(image))
    np.testing.assert_allclose(clip, image, atol=1e-5)
    thesis = SubsetSource(source, "slgcn27")  # SL-GCN's 27 points, all present in Holistic
    assert thesis.layout.num_nodes == 27 and thesis.load(CLIP).shape == (57, 27, 4)


def _foreign_pose(path, component="BODY_135"):
    header = PoseHeader(0.2, PoseHeaderDimensions(640, 480), [
        PoseHeaderComponent(component, ["NOSE", "NECK", "RSHOULDER"], [(0, 1), (1, 2)], [(255, 0, 0)] * 2, "XYC")])
    data = np.arange(4 * 3 * 2, dtype=np.float32).reshape(4, 1, 3, 2) + 1
    confidence = np.ones((4, 1, 3), np.float32)
    confidence[2, 0, 1] = 0  # one missed point
    with open(path, "wb") as handle:
        Pose(header, NumPyPoseBody(25, data, confidence)).write(handle)


def test_a_foreign_layout_is_read_from_its_header(tmp_path, caplog):
    """layout=auto on a file no MediaPipe layout fits reads the header's own layout (and says so);
    a MediaPipe layout asked for by name is one line naming the file and its components; a subset
    the layout lacks is one line naming the whole fix."""
    _foreign_pose(tmp_path / "clip1.pose")
    source = open_keypoint_source("pose_format", path=tmp_path)
    with caplog.at_level(logging.INFO):
        layout = source.layout
    assert layout.names == ("BODY_135:NOSE", "BODY_135:NECK", "BODY_135:RSHOULDER")
    assert layout.edges == ((0, 1), (1, 2)) and layout.channels == ("x", "y", "visibility")
    said = " ".join(r.getMessage() for r in caplog.records)
    assert f"layout {layout.name} (pose.options.layout=auto, read from clip1.pose): no MediaPipe layout fits" in said
    assert "BODY_135 (3 points, XYC)" in said and "subsets all)" in said  # no SL-GCN points in 3 nodes
    clip = source.load("clip1")
    assert clip.shape == (4, 3, 3) and np.isnan(clip[2, 1]).all()
    np.testing.assert_allclose(clip[0, 0], [1 / 640, 2 / 480, 1.0])
    header = open_keypoint_source("pose_format", path=tmp_path, layout="header")  # the same, asked for
    assert header.layout == layout
    np.testing.assert_array_equal(header.load("clip1"), clip)
    with pytest.raises(DataError) as error:
        open_keypoint_source("pose_format", path=tmp_path, layout="mediapipe_holistic").layout
    message = str(error.value)
    assert "\n" not in message and "clip1.pose" in message and "BODY_135 (3 points, XYC)" in message
    with pytest.raises(DataError) as error:
        SubsetSource(source, "slgcn27")  # conf/pose/pose_format.yaml's default subset
    message = str(error.value)
    assert "\n" not in message and "no keypoint subset 'slgcn27'" in message and "channels x, y, visibility" in message
    assert "set pose.subset=all" in message
    (tmp_path / "broken.pose").write_bytes(b"not a pose file")
    with pytest.raises(DataError, match="broken.pose"):
        source.load("broken")
    with pytest.raises(DataError, match="options"):
        open_keypoint_source("pose_format", path=tmp_path, layut="header")


def test_retargeting_accepts_a_pose_file(extracted, pose_dir, tmp_path):
    out, _, _ = extracted
    from_npy = R.retarget_video(out, CLIP, tmp_path / "npy")
    from_pose = R.retarget_video(pose_dir / f"{CLIP}.pose", out_dir=tmp_path / "pose")
    assert from_pose["video_id"] == CLIP and from_pose["fps"] == 25.0
    columns = {"hand": R.HAND_FILE_VALUES, "upper_body": R.UPPER_FILE_VALUES}
    for part, width in columns.items():
        assert from_pose[part]["status"] == "ok"
        expected = load_motion(from_npy[part]["path"], expected_columns=width).frames
        got = load_motion(from_pose[part]["path"], expected_columns=width).frames
        np.testing.assert_allclose(got, expected, atol=1e-4)  # the same motion: float32 in the file


def test_retargeting_a_pose_without_metric_hands(extracted, pose_dir, tmp_path):
    """A `.pose` as pose-format's own video_to_pose writes it (no metric hands): each image hand
    is scaled to an adult hand on the world wrist; the arms come from the world pose as before."""
    out, _, _ = extracted
    pose = Pose.read((pose_dir / f"{CLIP}.pose").read_bytes()).get_components(COMPONENTS[:4])
    path = tmp_path / f"{CLIP}.pose"
    with open(path, "wb") as handle:
        pose.write(handle)
    result = R.retarget_video(path, out_dir=tmp_path / "motions")
    reference = R.retarget_video(out, CLIP, tmp_path / "npy")
    assert result["hand"]["status"] == "ok" and result["hand"]["side"] == "right"
    hand = load_motion(result["hand"]["path"], expected_columns=R.HAND_FILE_VALUES)
    assert hand.num_frames == 57 and 0.0 <= hand.frames[:, 7:].min() and hand.frames[:, 7:].max() <= 2.0
    got = R.upper_body_joints(load_motion(result["upper_body"]["path"], expected_columns=R.UPPER_FILE_VALUES).frames)
    expected = R.upper_body_joints(load_motion(reference["upper_body"]["path"],
                                               expected_columns=R.UPPER_FILE_VALUES).frames)  # fmt: skip
    np.testing.assert_allclose(got["right_elbow"], expected["right_elbow"], atol=1e-4)
    # Without any world component the image is lifted (shoulders 0.36 m): still a bent right arm,
    # if less bent than the world pose says (MediaPipe's image depth is flatter): 0.79 vs 1.50 rad.
    write_holistic_pose(tmp_path / "image_only.pose", np.load(out / f"{CLIP}.npy"), 25.0, 480, 320)
    lifted = R.retarget_video(tmp_path / "image_only.pose", out_dir=tmp_path / "lifted")
    joints = R.upper_body_joints(load_motion(lifted["upper_body"]["path"], expected_columns=R.UPPER_FILE_VALUES).frames)
    assert 0.5 < np.median(joints["right_elbow"]) < np.median(expected["right_elbow"])
    assert read_status(out, CLIP)["width"] == 480


def test_command_line_retargets_pose_files(pose_dir, tmp_path, capsys):
    from aslexp.pose.extract_cli import extract_main

    rc = extract_main([str(pose_dir / f"{CLIP}.pose"), "--motions", "--out", str(tmp_path)])
    printed = capsys.readouterr().out
    assert rc == 0, printed
    assert "hand ok: 1" in printed and "upper_body ok: 1" in printed
    assert (tmp_path / "motions" / "hand" / f"{CLIP}.txt").is_file()
    assert extract_main([str(pose_dir / f"{CLIP}.pose"), "--out", str(tmp_path)]) == 2  # bad input
    assert "with --motions" in capsys.readouterr().err
