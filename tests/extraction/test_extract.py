"""Extraction on a real WLASL clip: shapes and masks, handedness, caching and resume, bad input,
overlay, retargeting of the real landmarks and the command line."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
from PIL import Image

from aslexp.keypoints import holistic as H
from aslexp.pose import retarget as R
from aslexp.pose.extract import ExtractOptions, extract_videos, read_status, render_overlays
from aslexp.pose.extract_cli import extract_main
from aslexp.sim.motion import load_motion

from .conftest import CLIP, hand_frames

pytestmark = pytest.mark.usefixtures("worker_env")

LEFT, RIGHT = H.LEFT_HAND_OFFSET, H.RIGHT_HAND_OFFSET


def test_arrays_have_the_layout_shape_and_nan_masks(extracted):
    out, summary, _ = extracted
    image = np.load(out / f"{CLIP}.npy")
    world = np.load(out / "world" / f"{CLIP}.npy")
    assert image.dtype == np.float32 and image.shape == (57, 75, 4)
    assert world.dtype == np.float32 and world.shape == (57, 75, 3)
    assert json.loads((out / "layout.json").read_text())["names"] == list(H.NAMES)
    # The body is seen in every frame, with visibilities in [0, 1].
    assert np.isfinite(image[:, : H.NUM_POSE]).all()
    assert 0.0 <= np.nanmin(image[..., 3]) and np.nanmax(image[..., 3]) <= 1.0
    # The signer's right hand is seen throughout (Holistic, gaps filled by MediaPipe Hands) ...
    assert np.isfinite(image[:, RIGHT : RIGHT + 21]).all() and np.isfinite(world[:, RIGHT : RIGHT + 21]).all()
    # ... the left stays below the frame: masked with NaN in every channel, never zero (MediaPipe
    # "finds" it in a few frames on some CPUs: those frames hold a whole hand).
    left = hand_frames(out, CLIP, "left")
    found = np.isfinite(world[:, LEFT : LEFT + 21]).all(axis=(1, 2))
    assert left <= 5 and np.isnan(image[~found, LEFT : LEFT + 21]).all() and np.isnan(world[~found, LEFT : LEFT + 21]).all()
    assert not (image == 0).all(axis=-1).any()
    status = read_status(out, CLIP)
    assert status["counts"]["pose"] == 57 and status["counts"]["right_hand"] == 57
    assert status["counts"]["left_hand"] == left


def test_hands_are_on_the_signers_side(extracted):
    """The image is not mirrored: the signer's right hand is the one at the pose's right wrist,
    and its 3D shape is a right hand (finger angles mostly inside the model's limits)."""
    out, _, _ = extracted
    image = np.load(out / f"{CLIP}.npy")
    world = np.load(out / "world" / f"{CLIP}.npy").astype(float)
    to_right = np.linalg.norm(image[:, RIGHT, :2] - image[:, 16, :2], axis=1)
    to_left = np.linalg.norm(image[:, RIGHT, :2] - image[:, 15, :2], axis=1)
    assert np.median(to_right) < 0.05 and (to_right < to_left).all()
    # World hand anchored on the pose wrist, in metres (a hand is ~0.15-0.25 m long).
    np.testing.assert_allclose(world[:, RIGHT], world[:, 16], atol=1e-6)
    length = np.linalg.norm(world[:, RIGHT + 12] - world[:, RIGHT], axis=1)
    assert 0.1 < np.median(length) < 0.3
    # Read as a right hand the four fingers flex (> 0); read as a left hand they would all bend
    # backwards (the thumb, flexing about the palm normal, reads the same either way).
    hand = world[:, RIGHT : RIGHT + 21] @ R.MP_TO_HUMANOID.T
    as_right = np.median(R.hand_angles(hand, R.final_hand_model())[:, 3:], axis=0)
    as_left = np.median(R.hand_angles(R.mirror_hand(hand), R.final_hand_model())[:, 3:], axis=0)
    assert np.median(as_right) > 0.2 and (as_right > -0.1).all()
    assert np.median(as_left) < -0.2


def test_bad_inputs_fail_clearly_and_alone(extracted):
    out, summary, _ = extracted
    assert sorted(summary.extracted) == sorted([CLIP, "part"])
    reasons = {vid: f["reason"] for vid, f in summary.failed.items()}
    assert reasons == {"nobody": "no_person", "beyond": "range_beyond_video", "empty": "empty",
                       "garbage": "unreadable", "missing": "missing"}
    assert "no person found in any of 15 frames" in summary.failed["nobody"]["error"]
    assert "frame range 500..520 lies beyond the video's 57 frames" in summary.failed["beyond"]["error"]
    assert summary.failure_counts() == {"no_person": 1, "range_beyond_video": 1, "empty": 1,
                                        "unreadable": 1, "missing": 1}
    report = summary.report()
    assert "FAILED garbage" in report and "failed (empty): 1" in report
    assert not (out / "nobody.npy").exists()  # no array for a clip without a person
    assert np.load(out / "part.npy").shape == (20, 75, 4)


def test_rerun_skips_finished_videos_and_resumes(extracted_copy):
    out, jobs = extracted_copy
    before = os.path.getmtime(out / f"{CLIP}.npy")
    log_size = (out / "worker.log").stat().st_size
    summary = extract_videos(jobs, out, ExtractOptions(cpus=1), progress=False)
    assert (out / "worker.log").stat().st_size == log_size  # nothing to do: no worker started
    assert sorted(summary.cached) == sorted([CLIP, "part"]) and not summary.extracted
    assert set(summary.failed) == {"nobody", "beyond", "empty", "garbage", "missing"}
    assert os.path.getmtime(out / f"{CLIP}.npy") == before
    # An interrupted run: "part" has an array but no status yet -> only it is redone.
    (out / "status" / "part.json").unlink()
    (out / "part.npy").write_bytes(b"partial")
    summary = extract_videos(jobs[:2], out, ExtractOptions(cpus=1), progress=False)
    assert summary.extracted == ["part"] and summary.cached == [CLIP]
    assert np.load(out / "part.npy").shape == (20, 75, 4)


def test_overlay_is_drawn(extracted, tmp_path):
    out, _, _ = extracted
    results = render_overlays([CLIP, "nobody"], out, tmp_path, fmt="gif", cpus=1)
    assert results["nobody"]["status"] == "failed"
    result = results[CLIP]
    assert result["status"] == "ok" and result["frames"] == 57
    gif = Image.open(result["overlay"])
    assert gif.n_frames == 57 and gif.size == (480, 320)
    still = np.asarray(Image.open(result["still"]).convert("RGB")).astype(int)
    # The signer's right hand is drawn in red (BGR 40, 80, 255) around its landmarks.
    image = np.load(out / f"{CLIP}.npy")
    x, y = (image[result["still_frame"] - 1, RIGHT + 8, :2] * [480, 320]).astype(int)
    patch = still[max(y - 6, 0) : y + 7, max(x - 6, 0) : x + 7]
    red = (patch[..., 0] > 200) & (patch[..., 1] < 120) & (patch[..., 2] < 90)
    assert red.any()


def test_real_clip_motions_within_limits_and_loadable(extracted, tmp_path):
    out, _, _ = extracted
    result = R.retarget_video(out, CLIP, tmp_path)
    assert result["hand"]["status"] == "ok" and result["hand"]["side"] == "right"
    assert result["upper_body"]["status"] == "ok"
    hand = load_motion(result["hand"]["path"], expected_columns=R.HAND_FILE_VALUES)
    assert hand.num_frames == 57 and np.isclose(hand.dt[0], 1 / 25)
    assert 0.0 <= hand.frames[:, 7:].min() and hand.frames[:, 7:].max() <= 2.0
    upper = load_motion(result["upper_body"]["path"], expected_columns=R.UPPER_FILE_VALUES)
    joints = R.upper_body_joints(upper.frames)
    kin = R.upper_body_kinematics()
    for name, width in R.UPPER_BODY_COLUMNS:
        if width == 1 and kin.joints[name].lower is not None:
            j = kin.joints[name]
            assert j.lower <= joints[name].min() and joints[name].max() <= j.upper, name
        elif width == 4:
            np.testing.assert_allclose(np.linalg.norm(joints[name], axis=1), 1.0, atol=1e-9)
    # The whistle is made at the mouth: the right elbow is bent, the right hand raised well
    # above its elbow, the unseen left arm hangs.
    assert np.median(joints["right_elbow"]) > 1.2
    body, hands = R.upper_body_keypoints(upper.frames)
    assert np.median(hands["right"][:, 12, 1] - body["right_elbow"][:, 1]) > 0.3
    assert np.median(body["right_wrist"][:, 1] - body["left_wrist"][:, 1]) > 0.5
    # The left hand is out of view: the report says how little of it was seen; never seen, its
    # fingers stay open.
    left = hand_frames(out, CLIP, "left")
    assert result["upper_body"]["left_hand"]["coverage"] == pytest.approx(left / 57, abs=0.01)
    if not left:
        assert np.all(joints["l_index_prox"] == 0.0)


def test_imitation_env_loads_the_hand_motion(extracted, tmp_path):
    from aslexp.envs.imitation import ImitationEnv

    out, _, _ = extracted
    path = R.retarget_video(out, CLIP, tmp_path)["hand"]["path"]
    env = ImitationEnv(path, body="final_hand")
    try:
        env.reset(seed=0)
        _, reward, terminated, _, _ = env.step(env.reference_action())
        assert np.isfinite(reward) and not terminated
    finally:
        env.close()


def test_command_line(extracted_copy, videos, capsys):
    out, _ = extracted_copy
    rc = extract_main([str(videos / f"{CLIP}.mp4"), "--out", str(out), "--motions", "--quiet"])
    printed = capsys.readouterr().out
    assert rc == 0, printed
    assert "0 extracted, 1 already done (cached), 0 failed" in printed
    assert (out / "motions" / "hand" / f"{CLIP}.txt").is_file()
    assert (out / "motions" / "upper_body" / f"{CLIP}.txt").is_file()
    # A partial batch is no error: the rest is written, the failure listed with its reason (exit 0).
    rc = extract_main([str(videos / f"{CLIP}.mp4"), str(out / "nothing-here.mp4"), "--out", str(out), "--quiet"])
    printed = capsys.readouterr().out
    assert rc == 0 and "FAILED nothing-here" in printed and "done with 1 problem(s) in 2 input(s)" in printed
    # Nothing succeeded: exit 1; bad arguments: exit 2 (as every aslexp command).
    rc = extract_main([str(out / "nothing-here.mp4"), "--out", str(out), "--quiet"])
    assert rc == 1 and "FAILED nothing-here" in capsys.readouterr().out
    assert extract_main(["--workers", "0", str(videos), "--out", str(out)]) == 2


def test_imitation_env_loads_the_upper_body_motion(extracted, data_root, tmp_path):
    """No upper-body body config exists yet: describe the thesis humanoid inline, with the
    76-column layout (hips, knees and ankles are fixed in the URDF: read and ignored)."""
    from aslexp.envs.imitation import ImitationEnv

    out, _, _ = extracted
    path = R.retarget_video(out, CLIP, tmp_path)["upper_body"]["path"]
    body = {"name": "whole_upper_humanoid", "urdf": str(data_root / "models" / "whole_upper_humanoid.urdf"),
            "motion_layout": [[name, width] for name, width in R.UPPER_BODY_COLUMNS],
            "joint_groups": {"all": ["*"]}, "self_collision": False,
            "end_effectors": ["right_wrist", "left_wrist"], "end_effector_offset": [0.0, 0.0, 0.0]}
    env = ImitationEnv(path, body=body, env="default")
    try:
        assert env.layout.motion_columns == R.UPPER_FILE_VALUES and env.layout.num_joints == 38
        env.reset(seed=0)
        _, reward, terminated, _, _ = env.step(env.reference_action())
        assert np.isfinite(reward) and not terminated
    finally:
        env.close()


def test_an_mp4_overlay_is_h264_as_browsers_play_it(extracted, tmp_path):
    import subprocess

    from aslexp.viz.video import ffmpeg_executable

    out, _, _ = extracted
    result = render_overlays([CLIP], out, tmp_path, fmt="mp4", cpus=1)[CLIP]
    assert result["status"] == "ok" and result["codec"] == "h264"
    probe = subprocess.run([ffmpeg_executable(), "-i", result["overlay"]], capture_output=True, text=True)
    assert "Video: h264" in probe.stderr and "yuv420p" in probe.stderr
