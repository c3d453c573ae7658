"""A performance in its source's keypoints, scored against the person (aslexp.signing), on a real
WLASL clip: 63185 ("whistle": the right hand at the mouth, the left out of view: MediaPipe finds it in
none or a few frames, by CPU), the session's
one MediaPipe extraction (conftest ``extracted``), retargeted by `aslexp extract --motions` from
its cache, then imitated by the upper body for one pass of the sign (2.3 s)."""

from __future__ import annotations

import contextlib
import io
import json
import logging
import shutil

import numpy as np
import pytest

import aslexp  # noqa: F401  (registers the environments)
from aslexp.envs.upper_body import UpperBodyImitationEnv
from aslexp.pose.extract_cli import extract_main
from aslexp.pose.source_frame import PARTS, frame_errors
from aslexp.rl.evaluate import evaluate
from aslexp.signing.keypoints import SigningSource, performance_points
from aslexp.signing.performance import (
    REFERENCE_STAGE,
    SIGNING_POSE,
    SIGNING_VIDEO,
    signing_metrics,
    stage_keypoints,
)
from aslexp.signing.scores import dtw_scores

from .conftest import CLIP, hand_frames


@pytest.fixture(scope="module")
def extraction(extracted, videos, tmp_path_factory):
    """(keypoint folder, the motion's report): `aslexp extract CLIP --motions --format pose` on a copy of
    the session's extraction (its cache: no MediaPipe run)."""
    out = tmp_path_factory.mktemp("signing") / "keypoints"
    shutil.copytree(extracted[0], out)
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        rc = extract_main([str(videos / f"{CLIP}.mp4"), "--out", str(out), "--motions", "--format", "pose", "--quiet"])
    assert rc == 0 and "1 already done (cached)" in printed.getvalue(), printed.getvalue()
    return out, json.loads((out / "motions" / "reports" / f"{CLIP}.json").read_text())


@pytest.fixture(scope="module")
def env(extraction, data_root):
    env = UpperBodyImitationEnv(extraction[0] / "motions" / "upper_body" / f"{CLIP}.txt", data_root=data_root)
    yield env
    env.close()


@pytest.fixture(scope="module")
def controller_run(env):
    """The controller alone, driven by the reference one step ahead, recorded over one pass of the motion."""
    steps = int(np.ceil(env.reference.duration * env.spec_env.control_hz))
    return evaluate(env, lambda obs, env: env.reference_action(1), steps, record=True).trajectory


def test_extraction_records_the_source_the_camera_and_the_retargeting_error(extraction, videos, tmp_path):
    out, report = extraction
    assert report["source"]["keypoints"] == str((out / f"{CLIP}.npy").resolve())
    video = videos / f"{CLIP}.mp4"  # the frames the keypoints were read from (a run draws the person on them)
    assert report["source"]["video"] == {"path": str(video), "first_frame": 0, "bytes": video.stat().st_size}
    assert (report["source"]["width"], report["source"]["height"], report["source"]["frames"]) == (480, 320, 57)
    camera, error = report["upper_body"]["camera"], report["upper_body"]["retargeting_error"]
    assert camera["kind"] == "orthographic" and camera["scale"] > 0 and len(camera["origin"]) == 2
    # what retargeting keeps of the person, frame by frame, in their shoulder widths
    assert 0 < error["body"]["mje"] < 0.2 and 0 < error["right_hand"]["mje"] < 0.6
    left = hand_frames(out, CLIP, "left")  # out of view: 0 frames, or a few where MediaPipe "finds" it
    if left:
        assert error["left_hand"]["frames"] == left and error["left_hand"]["mje"] > 0
    else:
        assert error["left_hand"] == {"mje": None, "note": "not in the source"}
    # A .pose input names itself as the source, with the same camera and error (the same keypoints).
    pose_out = tmp_path / "from_pose"
    with contextlib.redirect_stdout(io.StringIO()):
        assert extract_main([str(out / f"{CLIP}.pose"), "--motions", "--out", str(pose_out), "--quiet"]) == 0
    again = json.loads((pose_out / "motions" / "reports" / f"{CLIP}.json").read_text())
    assert again["source"]["keypoints"] == str((out / f"{CLIP}.pose").resolve())
    assert again["upper_body"]["camera"]["scale"] == pytest.approx(camera["scale"], rel=1e-3)
    assert again["upper_body"]["retargeting_error"]["body"]["mje"] == pytest.approx(error["body"]["mje"], abs=1e-3)


def test_the_reference_played_in_the_engine_reproduces_the_source_within_the_recorded_error(env, extraction):
    source, why = SigningSource.for_motion(env.motion.source)
    assert source is not None, why
    times = env.motion.times.copy()
    times[-1] -= 1e-9  # the last frame itself, not the loop's wrap to the first
    keypoints = source.camera.project(performance_points(env, env.reference.joints_many(times)))
    played = frame_errors(keypoints, source.image.keypoints, source.camera.width, source.camera.height)
    recorded = extraction[1]["upper_body"]["retargeting_error"]
    for part in PARTS:
        if recorded[part]["mje"] is None:
            assert played[part]["mje"] is None
            continue
        # the engine's body is the one extraction retargeted onto: the same error, not a new one
        assert played[part]["mje"] <= recorded[part]["mje"] + 1e-4, part
        assert played[part]["mje"] == pytest.approx(recorded[part]["mje"], abs=1e-4), part


def test_an_exact_replay_of_the_reference_scores_zero_against_the_reference(env, controller_run):
    source, _ = SigningSource.for_motion(env.motion.source)
    q_ref = controller_run["q_ref"]
    reference = stage_keypoints(env, source, q_ref)
    replay = stage_keypoints(env, source, q_ref.copy())
    scores = dtw_scores(replay, reference, source.camera.width, source.camera.height)
    assert all(scores[part]["dtw_mje"] == 0.0 for part in PARTS), scores
    assert scores["hands"]["dtwp"] == 0.0 and scores["hands"]["points"] == 42
    # ... and the simulated body (a controller that tracks, not replays) does not
    simulated = stage_keypoints(env, source, controller_run["q_sim"])
    assert dtw_scores(simulated, reference, source.camera.width, source.camera.height)["right_hand"]["dtw_mje"] > 0


def test_signing_metrics_score_each_stage_and_write_a_pose_file_the_field_reads(env, controller_run, extraction,
                                                                                 tmp_path):  # fmt: skip
    from pose_format import Pose
    from pose_format.utils.generic import detect_known_pose_format

    left = hand_frames(extraction[0], CLIP, "left")
    signing = signing_metrics(env, controller_run, tmp_path, stage="controller")
    assert set(signing["stages"]) == {REFERENCE_STAGE, "controller"}
    assert signing["source"] == extraction[1]["source"]["keypoints"]
    for scores in signing["stages"].values():
        # a hand not in the source: nothing to score (the left, unless MediaPipe "found" it in a frame)
        assert (scores["left_hand"]["dtw_mje"] is None) == (left == 0)
        assert scores["body"]["dtw_mje"] > 0 and scores["right_hand"]["dtw_mje"] > 0
        assert scores["hands"]["points"] == (42 if left else 21)
    json.dumps(signing)  # metrics.json takes it as it is
    with open(tmp_path / SIGNING_POSE, "rb") as handle:
        pose = Pose.read(handle.read())
    steps = signing["stages"]["controller"]["steps"]
    assert [c.name for c in pose.header.components] == ["POSE_LANDMARKS", "LEFT_HAND_LANDMARKS", "RIGHT_HAND_LANDMARKS"]
    assert pose.body.data.shape == (steps, 1, 75, 3) and pose.body.fps == env.spec_env.control_hz
    assert (pose.header.dimensions.width, pose.header.dimensions.height) == (480, 320)
    assert detect_known_pose_format(pose) == "holistic"
    # pose-evaluation's DTWp measure, from the two files as that toolkit reads them (pose-format's
    # shoulder normalisation, the hand's points, dtaidistance per point), gives the recorded number
    from dtaidistance import dtw_ndim

    with open(extraction[0] / f"{CLIP}.pose", "rb") as handle:
        person = Pose.read(handle.read())
    hands = [p.normalize().get_components(["RIGHT_HAND_LANDMARKS"]).body.data.filled(0)[:, 0, :, :2]
             for p in (pose, person)]  # fmt: skip
    toolkit = np.mean([dtw_ndim.distance_fast(np.ascontiguousarray(hands[0][:, k], dtype=np.float64),
                                              np.ascontiguousarray(hands[1][:, k], dtype=np.float64))
                       for k in range(21)])  # fmt: skip
    if left:  # the toolkit fills a hand's missing frames with 0 where aslexp leaves them out: no common number
        assert 0 < signing["stages"]["controller"]["hands"]["dtwp"] < 20
    else:
        assert signing["stages"]["controller"]["hands"]["dtwp"] == pytest.approx(toolkit, rel=1e-3)


def _mp4_frames(path) -> list[np.ndarray]:
    import imageio_ffmpeg

    reader = imageio_ffmpeg.read_frames(str(path))
    width, height = next(reader)["size"]
    return [np.frombuffer(raw, np.uint8).reshape(height, width, 3) for raw in reader]


def test_the_side_by_side_video_shows_the_video_the_person_the_agent_and_the_signing_hand(
        env, controller_run, videos, tmp_path):  # fmt: skip
    from PIL import Image

    from aslexp.viz.signing_video import HEADER

    signing = signing_metrics(env, controller_run, tmp_path, stage="controller", write_pose=False, video=True)
    drawn, steps = signing["video"], signing["stages"]["controller"]["steps"]
    assert drawn["files"] == [SIGNING_VIDEO, "signing.gif"] and drawn["video"] == str(videos / f"{CLIP}.mp4")
    frames = _mp4_frames(tmp_path / SIGNING_VIDEO)
    assert len(frames) == steps == drawn["frames"]  # one frame per control step of the pass
    assert Image.open(tmp_path / "signing.gif").n_frames == (steps + 1) // 2  # every second step
    # video | person's keypoints | agent, equal panels, then the right hand's close-ups (person | agent):
    # the left hand is never in the source's view, so it is not a signing hand
    panels, hands = drawn["panels"], drawn["hands"]
    assert list(panels) == ["video", "person", "agent"] and set(hands) == {"right"}
    panel_w, panel_h = panels["video"][2:]
    assert [p[0] for p in panels.values()] == [0, panel_w, 2 * panel_w] and all(p[2:] == [panel_w, panel_h]
                                                                                for p in panels.values())  # fmt: skip
    tile = hands["right"]["person"][2]
    assert hands["right"]["person"][:2] == [3 * panel_w, HEADER]
    assert hands["right"]["agent"][:2] == [3 * panel_w + tile, HEADER]
    assert drawn["size"] == [3 * panel_w + 2 * tile, HEADER + panel_h]
    assert frames[0].shape == (HEADER + panel_h, 3 * panel_w + 2 * tile, 3)
    # each hand (the person's, and the agent's smaller one) spans at least 128 pixels in its close-up
    assert tile >= 128 and min(hands["right"]["person_px"], hands["right"]["agent_px"]) >= 128
    assert hands["right"]["person_px"] <= tile and hands["right"]["agent_px"] <= tile
    # the framing is the body's: the person's head and shoulders and the agent's hips inside the box
    source, _ = SigningSource.for_motion(env.motion.source)
    left, top, right, bottom = drawn["box"]
    head = source.image.keypoints[:, [0, 11, 12], :2] * [source.camera.width, source.camera.height]
    assert left < np.nanmin(head[..., 0]) and np.nanmax(head[..., 0]) < right and top < np.nanmin(head[..., 1])
    assert bottom > source.camera.height * 0.9  # down to the waist: below the shoulders, near the frame's foot
    # the video panel is the video; the agent's points are drawn where its keypoints put them
    k = steps // 2
    video = frames[k][HEADER:, :panel_w].astype(float)
    assert video.std() > 15  # a picture, not a blank canvas
    agent = stage_keypoints(env, source, controller_run["q_sim"][:steps])[k]
    scale = panel_w / (right - left)
    for node in (0, 11, 12, 16):  # nose, shoulders, right wrist
        x, y = (agent[node, :2] * [source.camera.width, source.camera.height] - [left, top]) * scale
        x, y = int(round(x + 2 * panel_w)), int(round(y + HEADER))
        assert frames[k][y - 3:y + 4, x - 3:x + 4].max() > 170, node  # a drawn point on the dark canvas
    assert frames[k][HEADER + 5:HEADER + 40, 2 * panel_w + 5:2 * panel_w + 40].max() < 60  # the canvas itself


def test_without_a_known_video_the_side_by_side_video_has_the_keypoints_and_agent_panels(env, controller_run,
                                                                                        tmp_path, caplog):  # fmt: skip
    import dataclasses

    from aslexp.signing.performance import write_signing_video

    source, _ = SigningSource.for_motion(env.motion.source)
    steps = len(controller_run["time"]) // 2
    agent = stage_keypoints(env, source, controller_run["q_sim"][:steps])
    times = np.arange(1, steps + 1) / env.spec_env.control_hz
    with caplog.at_level(logging.INFO, logger="aslexp.signing"):
        drawn = write_signing_video(tmp_path, dataclasses.replace(source, video=None), agent, times, "agent", 30.0)
    assert "no video recorded" in drawn["no_video"] and any("no video panel" in r.getMessage() for r in caplog.records)
    assert list(drawn["panels"]) == ["person", "agent"] and set(drawn["hands"]) == {"right"}
    frames = _mp4_frames(tmp_path / SIGNING_VIDEO)
    assert len(frames) == steps and [frames[0].shape[1], frames[0].shape[0]] == drawn["size"]


def test_scores_drop_the_frames_a_part_is_missing_from(env, controller_run):
    source, _ = SigningSource.for_motion(env.motion.source)
    person = source.image.keypoints
    agent = stage_keypoints(env, source, controller_run["q_sim"])
    width, height = source.camera.width, source.camera.height
    lost = person.copy()
    lost[5:12, PARTS["right_hand"]] = np.nan  # MediaPipe loses the hand for a while
    dropped = np.delete(person, np.arange(5, 12), axis=0)
    masked, cut = dtw_scores(agent, lost, width, height), dtw_scores(agent, dropped, width, height)
    assert masked["right_hand"]["frames"][1] == len(person) - 7
    assert masked["right_hand"]["dtw_mje"] == pytest.approx(cut["right_hand"]["dtw_mje"], rel=0.01)
    assert masked["body"]["frames"][1] == len(person)  # the body is still compared on every frame


def test_the_handshape_score_sees_the_fingers_not_where_the_hand_is_or_how_it_is_turned(env):
    from aslexp.signing.scores import handshape

    source, _ = SigningSource.for_motion(env.motion.source)
    width, height = source.camera.width, source.camera.height
    hand = source.image.keypoints[:, list(PARTS["right_hand"])].copy()
    assert handshape(hand, hand, width, height)["handshape"] == 0.0
    # the same hand elsewhere, larger and turned in the image plane (a rotation about the camera axis)
    px = hand[..., :3] * [width, height, width]
    angle = 0.7
    turn = np.array([[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0], [0, 0, 1]])
    moved = (1.6 * px @ turn.T + [40.0, -25.0, 0.0]) / [width, height, width]
    assert handshape(moved, hand, width, height)["handshape"] == pytest.approx(0.0, abs=1e-6)
    # ... and another shape: the fingers drawn straight out from their bases
    straight = hand.copy()
    for base in (5, 9, 13, 17):
        step = hand[:, base, :3] - hand[:, 0, :3]
        for k in (1, 2, 3):
            straight[:, base + k, :3] = hand[:, base, :3] + 0.3 * k * step
    assert handshape(straight, hand, width, height)["handshape"] > 0.1


def test_a_hand_run_worn_by_the_upper_body_is_scored_against_the_persons_hand(env, extraction, data_root):
    """The hand body's run on the clip's hand motion: its fingers on the upper body's reference arm.
    Its reference stage is the upper body's own reference hand (one retargeting of the same
    landmarks), so the two score alike; an open hand is the floor beside them."""
    from aslexp.compose import compose
    from aslexp.jobs.signing import OPEN_HAND, hand_file, score_hand_clip
    from aslexp.signing.performance import score_trajectory

    out, report = extraction
    motion = out / "motions" / "upper_body" / f"{CLIP}.txt"
    assert hand_file(motion) == out / "motions" / "hand" / f"{CLIP}.txt" and hand_file(motion).is_file()
    scored = score_hand_clip(compose("imitate", ["body=hand15"]), hand_file(motion), env, data_root)
    side = report["hand"]["side"]
    assert scored["side"] == side == "right" and scored["body"] == "hand15"
    assert 0.5 < scored["rewards"]["controller"] <= 1.0 and not scored["diverged"]["controller"]
    stages = scored["stages"]
    steps = int(np.ceil(env.reference.duration * env.spec_env.control_hz))
    upper = evaluate(env, lambda obs, env: env.reference_action(1), steps, record=True).trajectory
    own, _ = score_trajectory(env, upper, SigningSource.for_motion(env.motion.source)[0], "q_ref")
    assert stages["reference"]["dtw_mje"] == pytest.approx(own[f"{side}_hand"]["dtw_mje"], abs=0.01)
    assert stages["reference"]["handshape"] == pytest.approx(own["handshape"][side], abs=0.01)
    for stage in ("reference", "controller", OPEN_HAND):
        assert 0.0 < stages[stage]["handshape"] < 2.0 and stages[stage]["dtwp"] > 0, stage
    assert stages[OPEN_HAND]["handshape"] != pytest.approx(stages["reference"]["handshape"], abs=1e-3)


def test_the_signing_table_of_a_video_scores_its_hand_body_beside_the_upper_body(extraction, data_root, tmp_path):
    """`aslexp signing signing.hand.enabled=true` on a video's extraction: the clip's gloss from WLASL
    (a video's report names none), the hand body's stages in its record, a row per clip in the table."""
    import os
    import sys

    import job_process

    out, _ = extraction
    run = tmp_path / "signing"
    proc = job_process.run([sys.executable, "-m", "aslexp.cli", "signing", f"signing.motions={out}",
                            "signing.hand.enabled=true", "signing.implausible=keep", "signing.read_back.enabled=false",
                            "plots=false", f"hydra.run.dir={run}"], capture_output=True, text=True, timeout=600,
                           env={**os.environ, "ASLEXP_DATA_ROOT": str(data_root)})
    assert proc.returncode == 0, proc.stderr[-3000:]
    (record,) = [json.loads(line) for line in (run / "clips.jsonl").read_text().splitlines()]
    assert record["gloss"] == "whistle" and record["hand"]["side"] == "right"
    assert set(record["hand"]["stages"]) == {"reference", "controller", "open hand"}
    table = json.loads((run / "signing.json").read_text())
    assert set(table["table"]["hand_body"]) == {"reference", "controller", "open hand"}
    assert table["table"]["keypoint_error"]["controller"]["handshape"]["n"] == 1
    assert any(line.startswith(f"| {CLIP} (whistle) |") for line in table["table_lines"])


def test_a_motion_without_source_keypoints_says_so_in_one_line(data_root, tmp_path, caplog):
    env = UpperBodyImitationEnv(data_root / "motions" / "upper_body" / "00433.txt", data_root=data_root)
    try:
        trajectory = evaluate(env, lambda obs, env: env.reference_action(1), 3, record=True).trajectory
        with caplog.at_level(logging.INFO, logger="aslexp.signing"):
            assert signing_metrics(env, trajectory, tmp_path) is None
    finally:
        env.close()
    lines = [r.getMessage() for r in caplog.records if r.name.startswith("aslexp.signing")]
    assert len(lines) == 1 and "not scored" in lines[0] and "00433" in lines[0] and "aslexp extract" in lines[0]
    assert not (tmp_path / SIGNING_POSE).exists()


def test_a_report_from_before_extraction_recorded_the_source_says_so(extraction, tmp_path):
    motions = tmp_path / "motions"
    shutil.copytree(extraction[0] / "motions", motions)
    report = motions / "reports" / f"{CLIP}.json"
    old = json.loads(report.read_text())
    old.pop("source")
    old["upper_body"].pop("camera")
    report.write_text(json.dumps(old))
    source, why = SigningSource.for_motion(motions / "upper_body" / f"{CLIP}.txt")
    assert source is None and str(report) in why and "names no source keypoint file" in why


def test_a_stage_that_blew_up_is_said_and_the_others_are_still_scored(env, controller_run, tmp_path):
    blown = {**controller_run, "q_sim": np.full_like(controller_run["q_sim"], np.nan)}
    signing = signing_metrics(env, controller_run, tmp_path, stage="controller", others={"blown": blown},
                              write_pose=False)  # fmt: skip
    assert "nothing to normalise by" in signing["stages"]["blown"]["error"]
    assert signing["stages"]["controller"]["body"]["dtw_mje"] > 0 and not (tmp_path / SIGNING_POSE).exists()


def test_a_mediapipe_pose_array_is_its_motions_source_at_its_fitted_aspect(data_root, tmp_path):
    from aslexp.pose.retarget import upper_body_kinematics
    from aslexp.pose.source_frame import motion_points
    from aslexp.sim.motion import load_motion

    array = sorted((data_root / "keypoints" / "wlasl-mediapipe-pose").glob("*.npy"))[0]
    with contextlib.redirect_stdout(io.StringIO()):
        assert extract_main([str(array), "--motions", "--out", str(tmp_path), "--quiet"]) == 0
    report = json.loads((tmp_path / "motions" / "reports" / f"{array.stem}.json").read_text())
    aspect = report["pose_array"]["lift"]["aspect"]
    assert report["source"]["keypoints"] == str(array.resolve()) and "fitted aspect" in report["source"]["size_from"]
    assert report["source"]["height"] == round(report["source"]["width"] * aspect)
    error = report["upper_body"]["retargeting_error"]
    assert error["body"]["mje"] > 0 and error["left_hand"]["mje"] is None and error["right_hand"]["mje"] is None
    # what a run reads back: the same keypoints and camera, which reproduce the recorded error
    source, why = SigningSource.for_motion(tmp_path / "motions" / "upper_body" / f"{array.stem}.txt")
    assert source is not None, why
    points = motion_points(load_motion(source.motion).frames, upper_body_kinematics(data_root))
    again = frame_errors(source.camera.project(points), source.image.keypoints, source.camera.width,
                         source.camera.height)  # fmt: skip
    assert again["body"]["mje"] == pytest.approx(error["body"]["mje"], abs=1e-5)


def test_a_run_on_a_real_sign_scores_its_stages_and_one_without_a_source_says_so(data_root, tmp_path):
    """`aslexp evaluate` (nothing trained) on one of the 291 clips' motions: metrics.json's `signing` holds
    the retargeted reference and the controller against the person, signing.pose is written; the thesis'
    hand letter, which has no source keypoints, says so in one line and scores nothing."""
    import os
    import subprocess
    import sys

    import job_process

    array = sorted((data_root / "keypoints" / "wlasl-mediapipe-pose").glob("*.npy"))[0]
    with contextlib.redirect_stdout(io.StringIO()):
        assert extract_main([str(array), "--motions", "--out", str(tmp_path / "kp"), "--quiet"]) == 0
    motion = tmp_path / "kp" / "motions" / "upper_body" / f"{array.stem}.txt"
    env = {**os.environ, "ASLEXP_DATA_ROOT": str(data_root), "MPLBACKEND": "Agg"}
    tiny = ["ppo.eval_steps=30", "ppo.eval_episodes=1", "plots=false", "render.gif=false", "render.mp4=false"]

    def evaluate_job(run: str, *overrides: str) -> subprocess.CompletedProcess:
        proc = job_process.run([sys.executable, "-m", "aslexp.cli", "evaluate", *overrides, *tiny,
                                f"hydra.run.dir={tmp_path / run}"], cwd=tmp_path, env=env, capture_output=True,
                               text=True, timeout=600)
        assert proc.returncode == 0, proc.stderr[-3000:]
        return proc

    evaluate_job("sign", f"motion.file={motion}", "body=upper_body")
    signing = json.loads((tmp_path / "sign" / "metrics.json").read_text())["signing"]
    assert set(signing["stages"]) == {REFERENCE_STAGE, "controller"}
    for stage in signing["stages"].values():
        assert stage["body"]["dtw_mje"] > 0 and stage["steps"] == 30
    assert (tmp_path / "sign" / SIGNING_POSE).is_file()

    proc = evaluate_job("letter", "motion=A")
    assert "signing" not in json.loads((tmp_path / "letter" / "metrics.json").read_text())
    said = [line for line in (proc.stdout + proc.stderr).splitlines() if "signing: not scored" in line]
    assert len(said) == 1 and not (tmp_path / "letter" / SIGNING_POSE).exists()
