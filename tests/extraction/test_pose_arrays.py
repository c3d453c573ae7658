"""The shared data's real MediaPipe Pose arrays (WLASL clips, (T, 132) normalised image landmarks, no
fingers) become upper-body motions: `aslexp extract --motions` writes each with its report (the
source, the frame rate and where it comes from, the lift, the fingers unobserved, the plausibility),
the motion loads as the upper body and plays in the imitation environment. No MediaPipe needed."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from aslexp.keypoints import holistic as H
from aslexp.pose import retarget as R
from aslexp.pose.extract_cli import extract_main
from aslexp.sim.motion import load_motion

POSE_DIR = Path("keypoints") / "wlasl-mediapipe-pose"
WLASL_JSON = Path("wlasl") / "WLASL_v0.3.json"
SEEN = "01457"  # "again", 40 frames, both arms seen throughout
ARM_BELOW_FRAME = "05307"  # 145 frames, the right wrist below the frame (visibility about 0.2) throughout


def _run(args, capsys) -> tuple[int, str, str]:
    rc = extract_main([str(a) for a in args])
    captured = capsys.readouterr()
    return rc, captured.out, captured.err


@pytest.fixture()
def two_clips(data_root, tmp_path) -> Path:
    folder = tmp_path / "pose"
    folder.mkdir()
    for vid in (SEEN, ARM_BELOW_FRAME):
        shutil.copy(data_root / POSE_DIR / f"{vid}.npy", folder)
    return folder


def test_pose_arrays_become_upper_body_motions_with_their_report(two_clips, data_root, tmp_path, capsys):
    out = tmp_path / "out"
    rc, printed, err = _run([two_clips, "--motions", "--out", out, "--wlasl", data_root / WLASL_JSON], capsys)
    assert rc == 0, printed + err
    assert "hand skipped: 2" in printed and "upper_body ok: 2" in printed
    assert "hand not made for 2 input(s): a MediaPipe Pose array (T, 132) holds no hand landmarks" in printed
    report = json.loads((out / "motions" / "reports" / f"{SEEN}.json").read_text())
    source = report["pose_array"]
    assert source["path"] == str(two_clips / f"{SEEN}.npy") and source["shape"] == [40, 132]
    assert source["fps"] == 25.0 and source["fps_from"] == f"{data_root / WLASL_JSON}: the fps of video {SEEN}"
    assert source["gloss"] == "again" and source["fingers"].startswith("not observed")
    lift = source["lift"]
    assert lift["aspect_from"].startswith("fitted") and 0.4 < lift["aspect"] < 0.7 and 0.05 < lift["depth_scale"] < 0.5
    upper = report["upper_body"]
    assert upper["right_hand"]["observed"] is False and upper["left_hand"]["observed"] is False
    assert upper["plausibility"]["plausible"] and upper["plausibility"]["reasons"] == {}
    assert upper["plausibility"]["checks"]["depth_to_width"] < 2  # MediaPipe's image depth rescaled: a body's
    motion = load_motion(upper["path"], expected_columns=R.UPPER_FILE_VALUES)
    assert motion.num_frames == 40 and motion.dt[0] == pytest.approx(1 / 25)
    joints = R.upper_body_joints(motion.frames)
    fingers = [f"{side}_{j}" for side in ("r", "l") for j in R.HAND_JOINTS]
    assert all(np.all(joints[name] == 0) for name in fingers)  # held at rest
    assert np.ptp(joints["right_elbow"]) > 0.3  # the arms sign: "again" bends the elbow
    # The resting arm below the frame: the better seen arm carries the sign, so it is plausible.
    below = json.loads((out / "motions" / "reports" / f"{ARM_BELOW_FRAME}.json").read_text())
    assert below["pose_array"]["arm_seen_share"]["right"] < 0.1 < 0.8 < below["pose_array"]["arm_seen_share"]["left"]
    assert "out_of_view" not in below["upper_body"]["plausibility"]["reasons"]


def test_a_clip_mostly_out_of_view_is_marked_implausible_and_counted(data_root, tmp_path, capsys):
    folder = tmp_path / "pose"
    folder.mkdir()
    for vid in ("70292", "70298", SEEN):  # 70292 and 70298: neither arm seen in half the frames
        shutil.copy(data_root / POSE_DIR / f"{vid}.npy", folder)
    rc, printed, _ = _run([folder, "--motions", "--out", tmp_path / "out"], capsys)
    assert rc == 0 and "upper_body implausible: 2" in printed and "upper_body ok: 3" in printed
    assert "2 upper-body motion(s) marked implausible in their reports (plausibility)" in printed
    report = json.loads((tmp_path / "out" / "motions" / "reports" / "70292.json").read_text())
    plausibility = report["upper_body"]["plausibility"]
    assert not plausibility["plausible"] and "out_of_view" in plausibility["reasons"]
    assert plausibility["checks"]["arm_seen_share"] < 0.5
    # Without --wlasl the frame rate is --fps's default, and the report says so.
    assert report["pose_array"]["fps_from"].startswith("25 fps, the default: WLASL's frame rate")


def test_the_lift_recovers_a_thesis_sign_from_its_image(data_root, tmp_path, capsys):
    """The thesis' sign 00433 through the humanoid's forward kinematics, laid out as MediaPipe Pose
    lays out an image (x / 1280, y / 720, the depth on x's scale times 5 as MediaPipe's image z):
    the fit finds the 16:9 aspect and the depth's scale, and the elbows come back."""
    motion = load_motion(data_root / "motions" / "upper_body" / "00433.txt", expected_columns=R.UPPER_FILE_VALUES)
    body, _ = R.upper_body_keypoints(motion.frames, data_root)
    pixels_per_unit = 150.0
    array = np.zeros((motion.num_frames, H.NUM_POSE, 4))
    for name, xyz in body.items():
        mp = xyz @ R.MP_TO_HUMANOID  # humanoid -> MediaPipe axes
        array[:, H.POSE_NAMES.index(name)] = np.stack(
            [0.5 + mp[:, 0] * pixels_per_unit / 1280, 0.3 + mp[:, 1] * pixels_per_unit / 720,
             5.0 * mp[:, 2] * pixels_per_unit / 1280, np.ones(len(mp))], axis=-1)  # fmt: skip
    (tmp_path / "in").mkdir()
    np.save(tmp_path / "in" / "00433.npy", array.reshape(len(array), -1))
    rc, printed, err = _run([tmp_path / "in" / "00433.npy", "--motions", "--out", tmp_path / "out", "--sigma", "0"],
                            capsys)  # fmt: skip
    assert rc == 0, printed + err
    report = json.loads((tmp_path / "out" / "motions" / "reports" / "00433.json").read_text())
    assert report["pose_array"]["lift"]["aspect"] == pytest.approx(720 / 1280, rel=0.02)
    assert report["pose_array"]["lift"]["depth_scale"] == pytest.approx(1 / 5, rel=0.02)
    back = R.upper_body_joints(load_motion(report["upper_body"]["path"], expected_columns=R.UPPER_FILE_VALUES).frames)
    thesis = R.upper_body_joints(motion.frames)
    for elbow in ("right_elbow", "left_elbow"):
        assert np.median(np.abs(back[elbow] - thesis[elbow])) < 0.05, elbow
    assert report["upper_body"]["plausibility"]["plausible"]


def test_pose_hand_points_turn_the_wrists_of_a_thesis_sign(data_root, tmp_path, capsys):
    """00433 laid out as a Pose array with Pose's own hand points (the model hand's index and pinky
    knuckles and thumb joint, which no finger angle moves): by default the wrists stay at rest; with
    --pose-hand-points they come back from the knuckles, and the report counts the frames they came from."""
    motion = load_motion(data_root / "motions" / "upper_body" / "00433.txt", expected_columns=R.UPPER_FILE_VALUES)
    body, hands = R.upper_body_keypoints(motion.frames, data_root)
    points = dict(body)
    for side in ("left", "right"):
        points.update({f"{side}_index": hands[side][:, 5], f"{side}_pinky": hands[side][:, 17],
                       f"{side}_thumb": hands[side][:, 2]})
    array = np.zeros((motion.num_frames, H.NUM_POSE, 4))
    for name, xyz in points.items():
        mp = xyz @ R.MP_TO_HUMANOID
        array[:, H.POSE_NAMES.index(name)] = np.stack(
            [0.5 + mp[:, 0] * 150 / 1280, 0.3 + mp[:, 1] * 150 / 720, 5.0 * mp[:, 2] * 150 / 1280,
             np.ones(len(mp))], axis=-1)  # fmt: skip
    array[:10, H.POSE_NAMES.index("right_index"), 3] = 0.2  # a guess for 10 frames: not a hand direction
    (tmp_path / "in").mkdir()
    np.save(tmp_path / "in" / "00433.npy", array.reshape(len(array), -1))
    thesis = R.upper_body_joints(motion.frames)
    for flags, out in (([], tmp_path / "plain"), (["--pose-hand-points"], tmp_path / "wrists")):
        rc, printed, err = _run([tmp_path / "in" / "00433.npy", "--motions", "--out", out, "--sigma", "0", *flags],
                                capsys)  # fmt: skip
        assert rc == 0, printed + err
        report = json.loads((out / "motions" / "reports" / "00433.json").read_text())
        back = R.upper_body_joints(load_motion(report["upper_body"]["path"], expected_columns=R.UPPER_FILE_VALUES).frames)
        if not flags:
            assert report["pose_hand_points"] is False and "right_wrist_from" not in report["upper_body"]
            assert np.all(back["right_wrist"] == 0) and np.all(back["left_wrist"] == 0)
            continue
        assert report["pose_hand_points"] is True
        assert report["upper_body"]["right_wrist_from"] == {"hand_landmarks": 0, "pose_hand_points": 69}
        assert report["upper_body"]["left_wrist_from"] == {"hand_landmarks": 0, "pose_hand_points": 79}
        for wrist in ("right_wrist", "left_wrist"):  # 00433's wrists move 0.1-1.06 rad; back to 2e-6 rad here
            assert np.abs(back[wrist][10:] - thesis[wrist][10:]).max() < 1e-3, wrist
        assert all(np.all(back[f"{side}_{j}"] == 0) for side in ("r", "l") for j in R.HAND_JOINTS)


def test_the_motion_plays_in_the_imitation_environment(two_clips, data_root, tmp_path, capsys):
    from aslexp.envs.imitation import ImitationEnv

    rc, _, _ = _run([two_clips / f"{SEEN}.npy", "--motions", "--out", tmp_path / "out"], capsys)
    assert rc == 0
    path = tmp_path / "out" / "motions" / "upper_body" / f"{SEEN}.txt"
    body = {"name": "whole_upper_humanoid", "urdf": str(data_root / "models" / "whole_upper_humanoid.urdf"),
            "motion_layout": [[name, width] for name, width in R.UPPER_BODY_COLUMNS],
            "joint_groups": {"all": ["*"]}, "self_collision": False,
            "end_effectors": ["right_wrist", "left_wrist"], "end_effector_offset": [0.0, 0.0, 0.0]}  # fmt: skip
    env = ImitationEnv(str(path), body=body)
    try:
        assert env.layout.motion_columns == R.UPPER_FILE_VALUES
        env.reset(seed=0)
        for _ in range(3):
            _, reward, terminated, _, _ = env.step(env.reference_action())
            assert np.isfinite(reward) and not terminated
    finally:
        env.close()


def test_a_frame_rate_that_is_not_positive_is_one_line(two_clips, tmp_path, capsys):
    rc, printed, err = _run([two_clips, "--motions", "--out", tmp_path / "out", "--fps", "0"], capsys)
    assert rc == 2 and err.strip() == ("aslexp extract: --fps 0: expected a positive frame rate (frames per second), "
                                       "e.g. --fps 25")
    assert not (tmp_path / "out" / "motions" / "upper_body").exists()


def test_the_documented_command_runs(data_root, two_clips, tmp_path, monkeypatch, capsys):
    """docs/extraction.md's command for the 291 clips, on two of them (the folder, the json and the
    models under the documented relative paths)."""
    import shlex

    from doc_commands import bash_lines

    doc = Path(__file__).resolve().parents[2] / "docs" / "extraction.md"
    command = next(line for line in bash_lines(doc) if "wlasl-mediapipe-pose" in line)
    words = shlex.split(command)
    assert words[:2] == ["aslexp", "extract"] and "--motions" in words and "--wlasl" in words
    (tmp_path / "work").mkdir()
    monkeypatch.chdir(tmp_path / "work")  # ../shared/data from here: the documented relative paths
    shared = tmp_path / "shared" / "data"
    (shared / POSE_DIR).parent.mkdir(parents=True)
    (shared / POSE_DIR).symlink_to(two_clips)
    (shared / WLASL_JSON).parent.mkdir(parents=True)
    (shared / WLASL_JSON).symlink_to(data_root / WLASL_JSON)
    (shared / "models").symlink_to(data_root / "models")  # the humanoid, from the data root found from here
    rc, printed, err = _run(words[2:], capsys)
    assert rc == 0 and "upper_body ok: 2" in printed, printed + err
    out = Path(words[words.index("--out") + 1])
    assert sorted(p.stem for p in (out / "motions" / "upper_body").glob("*.txt")) == [SEEN, ARM_BELOW_FRAME]
