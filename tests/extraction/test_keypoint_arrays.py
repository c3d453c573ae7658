"""Keypoint arrays to motions, and implausible motions said on the terminal.

No MediaPipe needed: the arrays are the thesis' own motions (letters A-E, signs 00433 ...) through the
models' forward kinematics, laid out as the other project's files are (MediaPipe Hands (T, 126) in
normalised image coordinates, the signer's left hand first; a `.pose` with a metric world
component), and the shared data's real MediaPipe Pose arrays of another project. `aslexp extract
... --motions` retargets them by the route extraction takes after MediaPipe (image hands made
metric as the worker makes them), so the letters come back to 1e-5 rad; the same with the depth
scaled up, or a foreign file lifted from its image depth, is warned about, joint and frames named.
"""

from __future__ import annotations

import json
import shlex
from pathlib import Path

import numpy as np
import pytest
from doc_commands import bash_lines

from aslexp.keypoints import holistic as H
from aslexp.keypoints.posefile import write_holistic_pose
from aslexp.pose import retarget as R
from aslexp.pose.extract_cli import extract_main
from aslexp.sim.motion import load_motion

WIDTH, HEIGHT = 640, 480
LETTERS = ("A", "B", "C", "D", "E")
EXTRACTION_DOC = Path(__file__).resolve().parents[2] / "docs" / "extraction.md"


def _thesis_hand(data_root, name):
    return load_motion(data_root / "motions" / "hand" / f"{name}.txt", expected_columns=R.HAND_FILE_VALUES)


def hands_array(data_root, name: str, depth: float = 1.0) -> np.ndarray:
    """The letter's right hand as a MediaPipe Hands array (T, 126): the model's keypoints (forward
    kinematics) in MediaPipe's axes, 400 px per model unit, x / width, y / height, z on x's scale
    (times ``depth``); the left hand never found (zeros)."""
    keypoints = R.hand_angles_to_keypoints(_thesis_hand(data_root, name).frames[:, 7:], data_root)
    mp = keypoints @ R.MP_TO_HUMANOID  # humanoid -> MediaPipe axes (a rotation: its transpose inverts it)
    image = np.stack([0.3 + mp[..., 0] * 400 / WIDTH, 0.5 + mp[..., 1] * 400 / HEIGHT,
                      depth * mp[..., 2] * 400 / WIDTH], axis=-1)  # fmt: skip
    hands = np.zeros((len(image), 2 * H.NUM_HAND, 3))
    hands[:, H.NUM_HAND :] = image
    return hands.reshape(len(image), 126)


def sign_pose(data_root, name: str, path: Path, depth: float = 1.0) -> Path:
    """A thesis sign as a `.pose` with its metric world (forward kinematics of the humanoid, in
    MediaPipe's axes, depth times ``depth``), as `aslexp extract --format pose` writes one."""
    motion = load_motion(data_root / "motions" / "upper_body" / f"{name}.txt", expected_columns=R.UPPER_FILE_VALUES)
    body, hands = R.upper_body_keypoints(motion.frames, data_root)
    world = np.full((motion.num_frames, H.NUM_NODES, 3), np.nan)
    for point, xyz in body.items():
        world[:, H.POSE_NAMES.index(point)] = xyz @ R.MP_TO_HUMANOID
    for side, offset in (("left", H.LEFT_HAND_OFFSET), ("right", H.RIGHT_HAND_OFFSET)):
        world[:, offset : offset + H.NUM_HAND] = hands[side] @ R.MP_TO_HUMANOID
    world[..., 2] *= depth
    seen = np.where(np.isfinite(world[..., :1]), 1.0, np.nan)
    image = np.concatenate([0.5 + 0.25 * world, seen], axis=-1)
    return write_holistic_pose(path, image, 1.0 / float(motion.dt[0]), WIDTH, HEIGHT, world=world)


def _run(args, capsys) -> tuple[int, str, str]:
    rc = extract_main([str(a) for a in args])
    captured = capsys.readouterr()
    return rc, captured.out, captured.err


@pytest.fixture()
def letters(data_root, tmp_path) -> Path:
    folder = tmp_path / "hands"
    folder.mkdir()
    for name in LETTERS:
        np.save(folder / f"{name}.npy", hands_array(data_root, name))
    return folder


def test_a_folder_of_hands_arrays_gives_hand_motions(letters, data_root, tmp_path, capsys):
    # A MediaPipe Pose array of the shared data (another project's) and a note beside the hands.
    pose = next(iter(sorted((data_root / "keypoints" / "wlasl-mediapipe-pose").glob("*.npy"))))
    np.save(letters / "body_only.npy", np.load(pose))
    (letters / "notes.txt").write_text("not keypoints\n")
    out = tmp_path / "out"
    # Without --motions, or without the frame size normalised hands need: bad input, one line.
    rc, printed, err = _run([letters, "--out", out], capsys)
    assert rc == 2 and "6 .npy input(s) are keypoints already" in err and "--motions" in err and "\n" not in err.strip()
    rc, printed, err = _run([letters, "--motions", "--out", out], capsys)
    assert rc == 2 and "A.npy: hand landmarks (41, 126)" in err and "add --frame-size WIDTHxHEIGHT" in err
    assert not (out / "motions" / "hand").exists()
    rc, printed, err = _run([letters, "--motions", "--out", out, "--frame-size", f"{WIDTH}x{HEIGHT}", "--sigma", "0"],
                            capsys)  # fmt: skip
    assert rc == 0, printed + err
    # Counted and said: what the folder held besides, the part hand arrays never give, the refusal.
    assert "skipped inputs: {'.txt file (not keypoints)': 1}" in printed
    assert "hand ok: 5" in printed and "upper_body skipped: 5" in printed
    assert "upper_body not made for 5 input(s): a MediaPipe Hands array (T, 126) holds no body" in printed
    # The MediaPipe Pose array beside them is a body: its upper body (tests/extraction/test_pose_arrays.py)
    assert "upper_body ok: 1" in printed and "hand not made for 1 input(s): a MediaPipe Pose array" in printed
    assert "FAILED" not in printed
    assert "WARNING" not in printed  # the thesis' own letters are plausible
    for name in LETTERS:  # the letters come back: the same route as a video's hands after MediaPipe
        motion = load_motion(out / "motions" / "hand" / f"{name}.txt", expected_columns=R.HAND_FILE_VALUES)
        expected = _thesis_hand(data_root, name).frames
        np.testing.assert_allclose(motion.frames[:, 7:], np.clip(expected[:, 7:], 0.0, 2.0), atol=1e-5)
        assert motion.dt[0] == pytest.approx(1 / 25)  # --fps: 25 by default


def test_one_hand_arrays_need_their_side(letters, tmp_path, capsys):
    one = tmp_path / "one"
    one.mkdir()
    np.save(one / "A.npy", np.load(letters / "A.npy")[:, 63:])  # (T, 63): the right hand alone
    size = ["--frame-size", "640x480", "--sigma", "0"]
    rc, _, err = _run([one / "A.npy", "--motions", "--out", tmp_path / "one_out", *size], capsys)
    assert rc == 2 and "A.npy: one hand (41, 63) without its side: add --hand right or --hand left" in err
    rc, printed, _ = _run([one / "A.npy", "--motions", "--out", tmp_path / "one_out", *size, "--hand", "right"], capsys)
    assert rc == 0 and "hand ok: 1" in printed, printed
    rc, printed, _ = _run([letters / "A.npy", "--motions", "--out", tmp_path / "two_out", *size], capsys)
    assert rc == 0 and "hand ok: 1" in printed, printed
    np.testing.assert_array_equal(load_motion(tmp_path / "one_out" / "motions" / "hand" / "A.txt").frames,
                                  load_motion(tmp_path / "two_out" / "motions" / "hand" / "A.txt").frames)


def test_the_documented_array_command_runs(letters, tmp_path, monkeypatch, capsys):
    """docs/extraction.md's keypoint-array command, as written, on a folder of the letters."""
    command = next(line for line in bash_lines(EXTRACTION_DOC) if "--frame-size" in line)
    words = shlex.split(command)
    assert words[:2] == ["aslexp", "extract"] and "--motions" in words
    monkeypatch.chdir(tmp_path)
    Path(words[2]).parent.mkdir(parents=True, exist_ok=True)
    Path(words[2]).symlink_to(letters)
    rc, printed, err = _run(words[2:], capsys)
    assert rc == 0 and "hand ok: 5" in printed, printed + err
    out = Path(words[words.index("--out") + 1]) / "motions" / "hand"
    assert sorted(p.stem for p in out.glob("*.txt")) == list(LETTERS)


def test_a_folder_of_other_files_says_what_it_skipped(tmp_path, capsys):
    (tmp_path / "in").mkdir()
    for name in ("a.txt", "b.txt", "c.csv"):
        (tmp_path / "in" / name).write_text("x\n")
    rc, _, err = _run([tmp_path / "in", "--out", tmp_path / "out"], capsys)
    assert rc == 2 and "no videos found" in err
    assert "'.txt file in a folder (not a video)': 2" in err and "'.csv file in a folder (not a video)': 1" in err


def test_implausible_motions_are_warned_on_the_terminal(data_root, tmp_path, capsys):
    """Real sequences made implausible (their depth scaled by 5), and a real foreign file (the
    shared MediaPipe Pose clip lifted from its image depth): WARNING lines naming the joints or the
    proportions and the frames, one per kind (two inputs of one kind: one counted line, each input's
    own line in its report); their normal versions: none."""
    folder = tmp_path / "in"
    folder.mkdir()
    normal = sign_pose(data_root, "00433", folder / "00433.pose")
    deep = sign_pose(data_root, "00433", folder / "00433_deep.pose", depth=5.0)
    clip = sorted((data_root / "keypoints" / "wlasl-mediapipe-pose").glob("*.npy"))[0]
    body = np.full((len(np.load(clip)), H.NUM_NODES, 4), np.nan, np.float32)
    body[:, : H.NUM_POSE] = np.load(clip).reshape(len(body), H.NUM_POSE, 4)
    foreign = write_holistic_pose(folder / f"{clip.stem}.pose", body, 25.0, WIDTH, HEIGHT)  # no world: lifted
    rc, printed, _ = _run([normal, deep, foreign, "--motions", "--out", tmp_path / "out"], capsys)
    assert rc == 0 and "upper_body ok: 3" in printed, printed
    warnings = [line for line in printed.splitlines() if "motion WARNING" in line]
    assert not [line for line in warnings if "00433 " in line]  # the thesis' sign as it is
    deep_line = next(line for line in warnings if "00433_deep upper_body" in line)
    assert "implausible proportions: the arms are 4.1 shoulder widths deep" in deep_line
    assert "in 79 of 79 frames (frames 0-78)" in deep_line
    assert deep_line.split("WARNING ", 1)[1].startswith(f"x2 (00433_deep upper_body, {clip.stem} upper_body), e.g. ")
    foreign = json.loads((tmp_path / "out" / "motions" / "reports" / f"{clip.stem}.json").read_text())
    foreign_line = foreign["upper_body"]["warnings"][0]  # its own line, in its report
    assert "shoulder widths deep" in foreign_line and "(frames " in foreign_line
    assert printed.rstrip().endswith("done with 1 problem(s) in 3 input(s), listed above (FAILED lines); the "
                                     "rest is written")  # the foreign clip has no hand: its hand FAILED
    assert len(warnings) == 1 and "2 warning(s) of 1 kind(s) above" in printed
    report = json.loads((tmp_path / "out" / "motions" / "reports" / "00433_deep.json").read_text())
    assert report["upper_body"]["warnings"] == [deep_line.split("upper_body: ", 1)[1]]
    assert report["upper_body"]["depth_to_width"] > 2 > json.loads(
        (tmp_path / "out" / "motions" / "reports" / "00433.json").read_text())["upper_body"]["depth_to_width"]


def test_a_joint_held_at_its_limit_is_named_with_its_frames(data_root, tmp_path, capsys):
    hands = tmp_path / "hands"
    hands.mkdir()
    np.save(hands / "B.npy", hands_array(data_root, "B"))
    np.save(hands / "B_deep.npy", hands_array(data_root, "B", depth=5.0))
    rc, printed, _ = _run([hands, "--motions", "--out", tmp_path / "out", "--frame-size", "640x480"], capsys)
    assert rc == 0, printed
    warnings = [line for line in printed.splitlines() if "motion WARNING" in line]
    assert warnings == ["  motion WARNING B_deep hand: thumb_prox held at its limit ([0.00, 2.00] rad; the keypoints "
                        "ask for more than 0.35 rad beyond) in 100% of its 45 frames (frames 0-44)"]


def test_detection_order_arrays_are_reordered_or_warned_about(letters, tmp_path, capsys):
    """MediaPipe's legacy Hands lists a lone hand in the first slot whichever it is: read as the
    signer's left hand first, the letter's right hand would be a mirrored left one; the array says
    so, and --hand-order detection gives each hand its side (here by position: the image's left
    half is the signer's right in a non-mirrored video)."""
    detection = tmp_path / "detection"
    detection.mkdir()
    hands = np.load(letters / "A.npy").reshape(-1, 42, 3)
    np.save(detection / "A.npy", np.concatenate([hands[:, 21:], hands[:, :21]], axis=1).reshape(len(hands), 126))
    size = ["--frame-size", "640x480", "--sigma", "0"]
    rc, printed, _ = _run([detection, "--motions", "--out", tmp_path / "as_left_right", *size], capsys)
    assert rc == 0 and "motion WARNING A: 1 of 1 hand files look like detection order" in printed, printed
    assert "add --hand-order detection" in printed
    rc, printed, _ = _run([detection, "--motions", "--out", tmp_path / "reordered", *size, "--hand-order", "detection"],
                          capsys)  # fmt: skip
    assert rc == 0 and "motion WARNING" not in printed, printed
    rc, _, _ = _run([letters / "A.npy", "--motions", "--out", tmp_path / "left_right", *size], capsys)
    np.testing.assert_array_equal(load_motion(tmp_path / "reordered" / "motions" / "hand" / "A.txt").frames,
                                  load_motion(tmp_path / "left_right" / "motions" / "hand" / "A.txt").frames)
