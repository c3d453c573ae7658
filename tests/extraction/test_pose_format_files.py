""".pose files that are not aslexp's own, made with pose-format from the whistle clip's real
MediaPipe keypoints: a format-0.0 file, pose-format's reduced Holistic (its own reduce_holistic),
hands-only and body-only files, reordered components and points, and an OpenPose file (pose-format's
own OpenPose reader). Each is read by the recognition source and retargeted by `aslexp extract
FILE.pose --motions` to the motions that are possible, or is one line saying what it has and what
is needed."""

from __future__ import annotations

import io
import json
import logging
import struct

import numpy as np
import pytest
from pose_format import Pose
from pose_format.utils.generic import reduce_holistic
from pose_format.utils.openpose import load_openpose

from aslexp.data.keypoints import open_keypoint_source
from aslexp.errors import DataError
from aslexp.keypoints import MEDIAPIPE_HANDS, MEDIAPIPE_HOLISTIC, MEDIAPIPE_POSE, SubsetSource
from aslexp.keypoints import holistic as H
from aslexp.keypoints.posefile import HAND_POINTS, LEFT, POSE, POSE_WORLD, REDUCED_POSE_POINTS, RIGHT, holistic_pose
from aslexp.pose import retarget as R
from aslexp.pose.extract_cli import extract_main
from aslexp.recognition.models.graph import hop_distances
from aslexp.sim.motion import load_motion

from .conftest import CLIP, hand_frames

pytestmark = pytest.mark.usefixtures("worker_env")

WIDTH, HEIGHT = 480, 320  # the whistle clip


@pytest.fixture(scope="module")
def whistle(extracted, tmp_path_factory):
    """The whistle clip laid out as pose-format's own video_to_pose writes Holistic (no metric hands,
    no face), the image arrays, and the motions retargeted from it (the reference)."""
    out, _, _ = extracted
    image = np.load(out / f"{CLIP}.npy")
    world = np.load(out / "world" / f"{CLIP}.npy")
    pose = holistic_pose(image, 25.0, WIDTH, HEIGHT, world=world).get_components([POSE, LEFT, RIGHT, POSE_WORLD])
    folder = tmp_path_factory.mktemp("reference")
    _write(pose, folder / f"{CLIP}.pose")
    reference = R.retarget_video(folder / f"{CLIP}.pose", out_dir=folder / "motions")
    assert reference["hand"]["status"] == reference["upper_body"]["status"] == "ok"
    return pose, image, reference


def _write(pose, path):
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as handle:
        pose.write(handle)
    return path


def _motions(path, out, capsys) -> tuple[int, str]:
    rc = extract_main([str(path), "--motions", "--out", str(out)])
    captured = capsys.readouterr()
    return rc, captured.out + captured.err


def _frames(result_or_path, part):
    width = R.HAND_FILE_VALUES if part == "hand" else R.UPPER_FILE_VALUES
    path = result_or_path if not isinstance(result_or_path, dict) else result_or_path[part]["path"]
    return load_motion(path, expected_columns=width).frames


def _write_v0_0(pose, path):
    """pose-format's format 0.0, as its reader reads it (PoseHeader.read and
    NumPyPoseBody.read_v0_0): the header of 0.2 with version 0.0; the body: fps and frame count as
    uint16, then per frame the number of people (uint16) and per person an id (int16) and its points,
    component after component, as float32 rows (x, y, z, confidence)."""
    header = io.BytesIO()
    pose.header.write(header)
    parts = [struct.pack("<f", 0.0), header.getvalue()[4:]]  # the first 4 bytes: the version
    data, confidence = np.ma.getdata(pose.body.data), np.asarray(pose.body.confidence)
    parts.append(struct.pack("<HH", int(pose.body.fps), len(data)))
    for t in range(len(data)):
        parts.append(struct.pack("<Hh", 1, 0))
        parts.append(np.concatenate([data[t, 0], confidence[t, 0, :, None]], axis=-1).astype("<f4").tobytes())
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"".join(parts))
    return path


def test_a_format_0_0_file_reads_and_retargets(whistle, tmp_path, capsys):
    pose, image, reference = whistle
    path = _write_v0_0(pose, tmp_path / "v0" / f"{CLIP}.pose")
    old = Pose.read(path.read_bytes())  # pose-format's own reader
    assert old.header.version == 0.0 and old.body.data.shape == pose.body.data.shape == (57, 1, 108, 3)
    np.testing.assert_array_equal(np.ma.getdata(old.body.data), np.ma.getdata(pose.body.data))
    # The recognition source reads the folder (its layout from the first file's header).
    source = open_keypoint_source("pose_format", path=path.parent)
    assert source.layout == MEDIAPIPE_HOLISTIC
    clip = source.load(CLIP)
    np.testing.assert_array_equal(np.isnan(clip), np.isnan(image))
    np.testing.assert_allclose(clip, image, atol=1e-5)
    rc, printed = _motions(path, tmp_path / "out", capsys)
    assert rc == 0 and "hand ok: 1" in printed and "upper_body ok: 1" in printed, printed
    for part in ("hand", "upper_body"):
        got = _frames(tmp_path / "out" / "motions" / part / f"{CLIP}.txt", part)
        np.testing.assert_allclose(got, _frames(reference, part), atol=1e-4)


def test_pose_formats_reduced_holistic(whistle, tmp_path, capsys):
    pose, image, reference = whistle
    reduced = reduce_holistic(pose)  # pose-format's own reduction
    assert [c.name for c in reduced.header.components] == [POSE, LEFT, RIGHT]  # the world is dropped
    assert reduced.header.components[0].points == list(REDUCED_POSE_POINTS) and len(REDUCED_POSE_POINTS) == 8
    path = _write(reduced, tmp_path / "reduced" / f"{CLIP}.pose")
    source = open_keypoint_source("pose_format", path=path.parent)
    layout = source.layout
    assert layout.name == "mediapipe_holistic_reduced" and layout.num_nodes == 50
    assert layout.names[:8] == tuple(H.NAMES[i] for i in H.REDUCED_BODY) and layout.names[8] == "left_hand_wrist"
    np.testing.assert_allclose(source.load(CLIP), image[:, list(H.REDUCED_BODY + H.HAND_NODES)], atol=1e-5)
    assert np.isfinite(hop_distances(50, layout.edges, layout.center)).all()  # one skeleton
    # SL-GCN's 27 points but the nose, the shoulders joined where the nose held them together.
    thesis = SubsetSource(source, "slgcn27")
    names = thesis.layout.names
    assert thesis.layout.num_nodes == 26 and "nose" not in names and names[thesis.layout.center] == "left_shoulder"
    assert np.isfinite(hop_distances(26, thesis.layout.edges, thesis.layout.center)).all()
    assert thesis.load(CLIP).shape == (57, 26, 4)
    # The full Holistic layout, asked for, says which points are missing.
    with pytest.raises(DataError) as error:
        open_keypoint_source("pose_format", path=path.parent, layout="mediapipe_holistic").load(CLIP)
    message = str(error.value)
    assert "\n" not in message and f"{CLIP}.pose" in message
    assert "POSE_LANDMARKS (8 points) lacks 25 needed point(s): NOSE, LEFT_EYE_INNER" in message
    # Motions: both. No world component and no head: the arms are lifted from the image (as for a
    # full file without world), the hand is the image hand, the neck stays upright.
    rc, printed = _motions(path, tmp_path / "out", capsys)
    assert rc == 0 and "hand ok: 1" in printed and "upper_body ok: 1" in printed, printed
    np.testing.assert_allclose(_frames(tmp_path / "out" / "motions" / "hand" / f"{CLIP}.txt", "hand"),
                               _frames(reference, "hand"), atol=1e-4)  # fmt: skip
    from aslexp.keypoints.posefile import write_holistic_pose

    lifted = R.retarget_video(write_holistic_pose(tmp_path / "image_only.pose", image, 25.0, WIDTH, HEIGHT),
                              out_dir=tmp_path / "lifted")  # fmt: skip
    got = R.upper_body_joints(_frames(tmp_path / "out" / "motions" / "upper_body" / f"{CLIP}.txt", "upper_body"))
    expected = R.upper_body_joints(_frames(lifted, "upper_body"))
    for joint in ("right_shoulder", "right_elbow", "left_elbow", "chest"):
        np.testing.assert_allclose(got[joint], expected[joint], atol=1e-4)
    np.testing.assert_allclose(got["neck"], np.tile([1.0, 0, 0, 0], (57, 1)))


def test_a_hands_only_file_gives_the_hand_motion(whistle, tmp_path, capsys):
    pose, image, reference = whistle
    hands = pose.get_components([RIGHT, LEFT])  # and in the other order
    path = _write(hands, tmp_path / "hands" / f"{CLIP}.pose")
    source = open_keypoint_source("pose_format", path=path.parent)
    assert source.layout == MEDIAPIPE_HANDS and source.layout.channels == ("x", "y", "z")
    np.testing.assert_allclose(source.load(CLIP), image[:, H.LEFT_HAND_OFFSET :, :3], atol=1e-5)
    assert SubsetSource(source, "slgcn27").layout.num_nodes == 20  # the hand points of SL-GCN's 27
    rc, printed = _motions(path, tmp_path / "out", capsys)
    assert rc == 0, printed
    assert "hand ok: 1" in printed and "upper_body failed: 1" in printed
    line = next(line for line in printed.splitlines() if "FAILED" in line)
    assert "upper body: not in the file: no component POSE_LANDMARKS" in line and "shoulders" in line
    np.testing.assert_allclose(_frames(tmp_path / "out" / "motions" / "hand" / f"{CLIP}.txt", "hand"),
                               _frames(reference, "hand"), atol=1e-4)  # fmt: skip
    assert not (tmp_path / "out" / "motions" / "upper_body" / f"{CLIP}.txt").exists()


def test_a_body_only_file_gives_the_upper_body(whistle, tmp_path, capsys):
    pose, image, reference = whistle
    path = _write(pose.get_components([POSE, POSE_WORLD]), tmp_path / "body" / f"{CLIP}.pose")
    source = open_keypoint_source("pose_format", path=path.parent)
    assert source.layout == MEDIAPIPE_POSE
    np.testing.assert_allclose(source.load(CLIP), image[:, : H.NUM_POSE], atol=1e-5)
    rc, printed = _motions(path, tmp_path / "out", capsys)
    assert rc == 0 and "upper_body ok: 1" in printed and "hand failed: 1" in printed, printed
    assert "no component LEFT_HAND_LANDMARKS; no component RIGHT_HAND_LANDMARKS (the hand motion needs one)" in printed
    got = R.upper_body_joints(_frames(tmp_path / "out" / "motions" / "upper_body" / f"{CLIP}.txt", "upper_body"))
    expected = R.upper_body_joints(_frames(reference, "upper_body"))
    np.testing.assert_allclose(got["right_elbow"], expected["right_elbow"], atol=1e-4)  # the same world arm
    assert np.all(got["r_index_prox"] == 0)  # no hand: the fingers stay open


def test_a_mediapipe_hands_array_gives_the_hand_motion(whistle, tmp_path, capsys):
    """The clip's hands as hand-only pipelines store them, (T, 126) with zeros for a hand not found:
    the same hand motion as its `.pose` without metric hands (image hands made metric the same
    way); no body, so no upper body, said once."""
    _, image, reference = whistle
    folder = tmp_path / "hands"
    folder.mkdir()
    hands = np.nan_to_num(image[:, H.LEFT_HAND_OFFSET :, :3], nan=0.0)
    np.save(folder / f"{CLIP}.npy", hands.reshape(len(hands), 126))
    rc = extract_main([str(folder), "--motions", "--out", str(tmp_path / "out"), "--frame-size", f"{WIDTH}x{HEIGHT}"])
    printed = capsys.readouterr().out
    assert rc == 0 and "hand ok: 1" in printed and "upper_body skipped: 1" in printed, printed
    assert "upper_body not made for 1 input(s): a MediaPipe Hands array (T, 126) holds no body" in printed
    got = _frames(tmp_path / "out" / "motions" / "hand" / f"{CLIP}.txt", "hand")
    np.testing.assert_allclose(got, _frames(reference, "hand"), atol=1e-4)


def test_implausible_motions_are_warned_and_plausible_ones_are_not(whistle, extracted, tmp_path, capsys):
    """The clip's metric landmarks (MediaPipe's world pose and Hands): no warning. Its image only
    (pose-format's video_to_pose without the world component, lifted from MediaPipe's image depth;
    its image hands too) and its depth scaled by 5: warnings naming the proportions, the joints held
    at their limits and the frames."""
    _, image, _ = whistle
    metric = R.retarget_video(extracted[0], CLIP, tmp_path / "metric")
    assert not metric["hand"]["warnings"] and not metric["upper_body"]["warnings"]
    assert metric["upper_body"]["depth_to_width"] < 1.5  # a body: 1.33 shoulder widths deep here
    from aslexp.keypoints.posefile import write_holistic_pose

    image_only = write_holistic_pose(tmp_path / "in" / f"{CLIP}.pose", image, 25.0, WIDTH, HEIGHT)
    deep = image.copy()
    deep[..., 2] *= 5
    deep = write_holistic_pose(tmp_path / "in" / f"{CLIP}_deep.pose", deep, 25.0, WIDTH, HEIGHT)
    rc = extract_main([str(image_only), str(deep), "--motions", "--out", str(tmp_path / "out")])
    printed = capsys.readouterr().out
    assert rc == 0 and "hand ok: 2" in printed and "upper_body ok: 2" in printed, printed
    warnings = [line for line in printed.splitlines() if "motion WARNING" in line]
    # one line per kind on the terminal, counting the inputs; each input's own lines in its report
    assert len([line for line in warnings if "implausible proportions" in line]) == 1
    assert len([line for line in warnings if " hand: ring_inter held at its limit" in line]) == 1
    for name in (CLIP, f"{CLIP}_deep"):
        report = json.loads((tmp_path / "out" / "motions" / "reports" / f"{name}.json").read_text())
        depth = next(line for line in report["upper_body"]["warnings"] if line.startswith("implausible proportions"))
        assert "shoulder widths deep" in depth and "of 57 frames (frames 0-56)" in depth
        assert any(line.startswith("ring_inter held at its limit") and "(frames " in line
                   for line in report["hand"]["warnings"])  # fmt: skip


def test_components_and_points_are_found_by_name(whistle, tmp_path):
    pose, image, _ = whistle
    shuffled = pose.get_components([RIGHT, POSE_WORLD, LEFT, POSE], {LEFT: list(reversed(HAND_POINTS))})
    assert shuffled.header.components[2].points[0] == "PINKY_TIP"
    path = _write(shuffled, tmp_path / "shuffled" / f"{CLIP}.pose")
    source = open_keypoint_source("pose_format", path=path.parent)
    assert source.layout == MEDIAPIPE_HOLISTIC
    np.testing.assert_allclose(source.load(CLIP), image, atol=1e-5)
    # A folder's layout comes from its first file; a later file without it is named in one line.
    _write(reduce_holistic(pose), tmp_path / "shuffled" / "zz_reduced.pose")
    with pytest.raises(DataError) as error:
        source.load("zz_reduced")
    message = str(error.value)
    assert "\n" not in message and "zz_reduced.pose: layout mediapipe_holistic needs" in message
    assert f"chosen from its first file {CLIP}.pose" in message


def test_mediapipe_components_lacking_points_are_read_as_they_are_with_a_warning(whistle, tmp_path, caplog):
    """A hands-only file whose right hand lacks a point fits no MediaPipe layout: layout=auto reads
    its header's own layout, and says louder than for a foreign format what the nearest one lacks."""
    pose, image, _ = whistle
    partial = pose.get_components([LEFT, RIGHT], {RIGHT: list(HAND_POINTS[:-1])})
    path = _write(partial, tmp_path / "partial" / f"{CLIP}.pose")
    source = open_keypoint_source("pose_format", path=path.parent)
    with caplog.at_level(logging.WARNING, logger="aslexp"):
        layout = source.layout
    assert layout.num_nodes == 41 and layout.names[21] == "RIGHT_HAND_LANDMARKS:WRIST"
    warning = next(r.getMessage() for r in caplog.records if r.levelno == logging.WARNING)
    assert "lack points every MediaPipe layout needs (nearest: mediapipe_hands: component RIGHT_HAND_LANDMARKS " \
           "(20 points) lacks 1 needed point(s): PINKY_TIP)" in warning
    np.testing.assert_allclose(source.load(CLIP)[:, 21:, :2], image[:, H.RIGHT_HAND_OFFSET : -1, :2], atol=1e-5)


def test_an_openpose_file_reads_as_sl_gcns_27_points_and_says_why_it_gives_no_motion(whistle, extracted, tmp_path,
                                                                                     capsys):  # fmt: skip
    """pose-format's own OpenPose reader on the clip's real hands and arms (pixels, 2D): layout=auto
    reads the header's own layout (no MediaPipe layout fits), whose names give SL-GCN's 27 points,
    the same as Holistic's 27 of the clip (conf/pose/pose_format.yaml's defaults need no other
    override); the motions need 3D MediaPipe points, so they are one line saying so."""
    pose, image, _ = whistle
    body_index = {"RShoulder": 12, "RElbow": 14, "RWrist": 16, "LShoulder": 11, "LElbow": 13, "LWrist": 15, "Nose": 0}
    from pose_format.utils.openpose import BODY_POINTS

    def flat(points):  # (V, 4) normalised -> OpenPose's [x, y, c, ...] in pixels, 0 = not found
        seen = np.isfinite(points).all(axis=-1)
        xyc = np.where(seen[:, None], points[:, :3] * [WIDTH, HEIGHT, 0] + [0, 0, 1], 0.0)
        return xyc.ravel().tolist()

    frames = {}
    for t, frame in enumerate(image):
        body = np.full((len(BODY_POINTS), 4), np.nan)
        for name, index in body_index.items():
            body[BODY_POINTS.index(name)] = frame[index]
        frames[t] = {"people": [{"pose_keypoints_2d": flat(body), "face_keypoints_2d": [0.0] * 210,
                                 "hand_left_keypoints_2d": flat(frame[H.LEFT_HAND_OFFSET : H.RIGHT_HAND_OFFSET]),
                                 "hand_right_keypoints_2d": flat(frame[H.RIGHT_HAND_OFFSET :])}]}  # fmt: skip
    openpose = load_openpose(frames, fps=25, width=WIDTH, height=HEIGHT)
    path = _write(openpose, tmp_path / "openpose" / f"{CLIP}.pose")
    source = open_keypoint_source("pose_format", path=path.parent)  # layout=auto
    assert source.layout.num_nodes == 137 and source.layout.channels == ("x", "y", "visibility")
    assert source.load(CLIP).shape == (57, 137, 3)
    thesis = SubsetSource(source, "slgcn27")
    holistic = _write(pose, tmp_path / "holistic" / f"{CLIP}.pose")
    reference = SubsetSource(open_keypoint_source("pose_format", path=holistic.parent), "slgcn27")
    assert thesis.layout.names == reference.layout.names and thesis.layout.edges == reference.layout.edges
    got, expected = thesis.load(CLIP), reference.load(CLIP)
    np.testing.assert_array_equal(np.isnan(got[..., 0]), np.isnan(expected[..., 0]))
    np.testing.assert_allclose(got[..., :2], expected[..., :2], atol=1e-5)  # x, y of the same 27 points
    left = hand_frames(extracted[0], CLIP, "left")  # out of view: none, or a few frames on some CPUs
    assert np.isfinite(got[..., 0]).sum() == 57 * 17 + left * 10  # nose, arms, the right hand, the left where found
    # Motions: 2D hands and no MediaPipe part; one line, no recognition option in it; bad input: exit 2.
    rc, printed = _motions(path, tmp_path / "out", capsys)
    assert rc == 2, printed
    line = next(line for line in printed.splitlines() if "FAILED" in line)
    assert "nothing to retarget" in line and "LEFT_HAND_LANDMARKS or RIGHT_HAND_LANDMARKS" in line
    assert "hand_left_keypoints_2d, hand_right_keypoints_2d are 2D (XYC)" in line
    assert "aslexp extract VIDEO --motions" in line and "pose.options" not in printed
    assert f"aslexp extract: {path}: nothing to retarget" in printed  # the one line on stderr
