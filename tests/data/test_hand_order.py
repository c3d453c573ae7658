"""Two-hand arrays in MediaPipe's detection order, on folders made from the
project's own data: the real MediaPipe Pose keypoints of the 291 WLASL clips carry each hand's
wrist, index and little-finger knuckles and thumb (landmarks 15-22, the signer's left and right),
and how visible each hand is. From them each test folder holds (T, 126) arrays of 21 landmarks per
hand (the real wrist, thumb, index and pinky points; the other knuckles between them, the finger
joints continued along wrist -> knuckle), a hand left out (zeros) in the frames where Pose saw it
with mean visibility <= 0.5:

- ``left_right/``: the signer's left hand first (the truth);
- ``detection/``: the same hands as MediaPipe's legacy Hands lists them: the slots in detection
  order (slot 1 filled whenever a hand is seen, slot 2 only when two are; the two hands exchange
  slots when one reappears (p = 0.3) and now and then while both are tracked (p = 0.03 a frame),
  seeded per clip);
- ``labelled/``: ``detection/`` plus ``<id>.handedness.npy``, MediaPipe's label of each slot
  ("Left" is the signer's right hand in these non-mirrored videos).
"""

from __future__ import annotations

import logging
import shutil

import numpy as np
import pytest
from hydra import compose, initialize_config_dir

from aslexp.data.keypoints import open_keypoint_source
from aslexp.data.wlasl_lex import build_wlasl_lex
from aslexp.errors import DataError
from aslexp.jobs._common import CONF_DIR
from aslexp.jobs.recognize import dataset_params
from aslexp.keypoints import ArrayFolderSource, hands

POSE_DIR = "keypoints/wlasl-mediapipe-pose"
SIDES = {"left": [15, 17, 19, 21], "right": [16, 18, 20, 22]}  # Pose: wrist, pinky, index, thumb
WARNING = "look like detection order"


def hand_21(points: np.ndarray) -> np.ndarray:
    """(T, 21, 3) MediaPipe hand landmarks from Pose's (T, 4, 3) wrist, pinky, index, thumb."""
    wrist, pinky, index, thumb = (points[:, k] for k in range(4))
    out = [wrist] + [wrist + f * (thumb - wrist) for f in (0.25, 0.5, 0.75, 1.0)]
    for knuckle in (index, index + (pinky - index) / 3, index + 2 * (pinky - index) / 3, pinky):
        out += [knuckle] + [knuckle + k * 0.3 * (knuckle - wrist) for k in (1, 2, 3)]
    return np.stack(out, axis=1)


def hand_arrays(pose: np.ndarray, rng: np.random.Generator):
    """(left_right (T, 42, 3), detection order (T, 42, 3), MediaPipe labels (T, 2))."""
    pose = pose.reshape(len(pose), 33, 4)
    person = ~np.all(pose == 0, axis=(1, 2))
    truth, seen = [], []
    for idx in SIDES.values():
        hand = hand_21(pose[:, idx, :3])
        visible = person & (pose[:, idx, 3].mean(axis=1) > 0.5)
        hand[~visible] = 0
        truth.append(hand)
        seen.append(visible)
    truth = np.concatenate(truth, axis=1)
    detection = np.zeros_like(truth)
    labels = np.full((len(pose), 2), "", dtype="<U5")
    order, before = [0, 1], set()
    for t in range(len(pose)):
        now = {k for k in (0, 1) if seen[k][t]}
        if len(now) == 1:
            order = [*now, 1 - next(iter(now))]
        elif len(now) == 2 and ((now != before and rng.random() < 0.3) or rng.random() < 0.03):
            order = order[::-1]
        for slot, k in enumerate(k for k in order if k in now):
            detection[t, 21 * slot : 21 * slot + 21] = truth[t, 21 * k : 21 * k + 21]
            labels[t, slot] = ("Right", "Left")[k]  # MediaPipe's mirrored label of the signer's side
        before = now
    return truth, detection, labels


@pytest.fixture(scope="module")
def folders(data_root, tmp_path_factory):
    base = tmp_path_factory.mktemp("hand_order")
    for name in ("left_right", "detection", "labelled"):
        (base / name).mkdir()
    for path in sorted((data_root / POSE_DIR).glob("*.npy")):
        truth, detection, labels = hand_arrays(np.load(path), np.random.default_rng(int(path.stem)))
        np.save(base / "left_right" / path.name, truth.reshape(len(truth), 126))
        np.save(base / "detection" / path.name, detection.reshape(len(truth), 126))
        np.save(base / "labelled" / path.name, detection.reshape(len(truth), 126))
        np.save(base / "labelled" / f"{path.stem}{hands.HANDEDNESS_SUFFIX}", labels)
    return base


def _source(folder, **options):
    return open_keypoint_source("array_folder", path=folder, layout="mediapipe_hands", **options)


def _side_errors(truth: ArrayFolderSource, read: ArrayFolderSource, video_id: str) -> tuple[int, int]:
    """(hands on the wrong side, hands) in one clip."""
    expected, got = truth.load(video_id), read.load(video_id)
    seen = np.isfinite(expected[:, ::21, 0])  # (T, 2): each side's wrist
    wrong = seen & ~np.isclose(np.nan_to_num(got[:, ::21, 0]), np.nan_to_num(expected[:, ::21, 0]))
    return int(wrong.sum()), int(seen.sum())


def test_the_folder_is_in_detection_order(folders):
    """What the issue measured on real MediaPipe Hands output holds here: slot 1 in every frame
    with a hand, slot 2 never alone, and the sides exchanged within clips."""
    first_only = second_only = hand_frames = swapped_clips = 0
    for path in sorted((folders / "detection").glob("*.npy")):
        detection = np.load(path).reshape(-1, 42, 3)
        truth = np.load(folders / "left_right" / path.name).reshape(-1, 42, 3)
        present = hands.slot_presence(detection)
        hand_frames += int(present.any(axis=1).sum())
        first_only += int((present[:, 0] & ~present[:, 1]).sum())
        second_only += int((~present[:, 0] & present[:, 1]).sum())
        both = present.all(axis=1)
        swapped_clips += bool(np.any(both & (detection[:, 0, 0] != truth[:, 0, 0])) and
                              np.any(both & (detection[:, 0, 0] == truth[:, 0, 0])))  # fmt: skip
    assert second_only == 0 and 0.2 < first_only / hand_frames < 0.4  # slot 2 empty in 27% of them
    assert swapped_clips >= 100  # the sides change slot within a clip


def test_detection_order_recovers_the_left_and_right_hands(folders, data_root):
    """Without handedness, by position: 98.5% of the hands of the 291 clips get the side Pose
    gave them, every hand of 278 clips. The rest: three TABLE clips whose forearms come into view
    already stacked (crossed), two clips (ME, MILK) whose signing hand Pose calls the left where
    position reads the right, and slips of a few frames when a lone hand moves fast."""
    truth, read = _source(folders / "left_right"), _source(folders / "detection", hand_order="detection")
    wrong = total = exact = 0
    for video_id in sorted(truth.available()):
        w, n = _side_errors(truth, read, video_id)
        wrong, total, exact = wrong + w, total + n, exact + (w == 0)
    assert total == 29839 and wrong / total < 0.015 and exact == 278
    # Where the sides are right, the arrays are the source's, bit for bit (a whole clip here:
    # 69 frames with both hands, 32 with one, 84 written with the slots exchanged).
    np.testing.assert_array_equal(read.load("05305"), truth.load("05305"))
    report = read.side_reports["05305"]
    assert (report.by_position, report.tracked, report.swapped, report.by_label) == (69, 32, 84, 0)


def test_stored_handedness_recovers_every_clip_exactly(folders):
    truth = _source(folders / "left_right")
    read = _source(folders / "labelled", hand_order="detection")
    assert read.available() == truth.available()  # the .handedness.npy files are no clips
    for video_id in sorted(truth.available()):
        np.testing.assert_array_equal(read.load(video_id), truth.load(video_id))
    # "milk" (36052): one hand, the signer's left by Pose, mostly on the image's left half: position
    # alone reads it as the right hand; the stored label gets it right.
    assert _side_errors(truth, _source(folders / "detection", hand_order="detection"), "36052")[0] > 90
    assert read.side_reports["36052"].by_label == 110 and read.side_reports["36052"].tracked == 0
    # Mirrored: MediaPipe's labels then mean what they say, so every side comes out exchanged.
    mirrored = _source(folders / "labelled", hand_order="detection", mirrored=True).load("01457")
    expected = truth.load("01457")
    np.testing.assert_array_equal(mirrored[:, :21], expected[:, 21:])


def _dataset(overrides, data_root):
    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        cfg = compose(config_name="recognize", overrides=["pose=mediapipe_hands", *overrides, "data.num_frames=32"])
    return build_wlasl_lex(None, dataset_params(cfg), root=data_root)


def test_a_build_warns_once_and_detection_builds_the_true_dataset(folders, data_root, caplog):
    caplog.set_level(logging.INFO, logger="aslexp")
    wrong = _dataset([f"pose.path={folders / 'detection'}"], data_root)
    warnings = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING and WARNING in r.getMessage()]
    assert len(warnings) == 1, warnings  # once per build, not once per file
    line = warnings[0]
    assert line.startswith(f"{folders / 'detection'}: 232 of 285 hand files look like detection order")
    assert "01457.npy" in line and "use pose.options.hand_order=detection" in line and "\n" not in line
    caplog.clear()
    right = _dataset([f"pose.path={folders / 'labelled'}", "pose.options.hand_order=detection"], data_root)
    truth = _dataset([f"pose.path={folders / 'left_right'}"], data_root)
    assert not [r for r in caplog.records if WARNING in r.getMessage()]  # neither the truth nor detection
    assert right.video_ids == truth.video_ids == wrong.video_ids
    np.testing.assert_array_equal(right.X, truth.X)
    np.testing.assert_array_equal(right.mask, truth.mask)
    assert not np.array_equal(wrong.X, truth.X)


def test_hand_options_are_checked(folders, tmp_path):
    with pytest.raises(DataError, match="hand_order = 'detected'.*left_right"):
        _source(folders / "detection", hand_order="detected")
    with pytest.raises(DataError, match="mirrored = 'yes'"):
        _source(folders / "detection", mirrored="yes")
    with pytest.raises(DataError, match="two-hand layout 'mediapipe_hands'.*'mediapipe_pose' has 33 nodes"):
        open_keypoint_source("array_folder", path=folders / "detection", layout="mediapipe_pose",
                             hand_order="detection")
    shutil.copy(folders / "detection" / "01457.npy", tmp_path / "01457.npy")
    np.save(tmp_path / "01457.handedness.npy", np.array([["Left", "Up"]] * len(np.load(tmp_path / "01457.npy"))))
    with pytest.raises(DataError, match=r"01457.handedness.npy: frame 0, slot 2: handedness 'Up'"):
        _source(tmp_path, hand_order="detection").load("01457")
    np.save(tmp_path / "01457.handedness.npy", np.zeros((3, 2)))
    with pytest.raises(DataError, match=r"01457.handedness.npy: handedness has shape \(3, 2\), expected \(\d+, 2\)"):
        _source(tmp_path, hand_order="detection").load("01457")


def test_a_reused_build_says_its_warning_again(folders, data_root, tmp_path, caplog):
    from aslexp.data.wlasl_lex import build_or_load

    with initialize_config_dir(config_dir=CONF_DIR, version_base="1.3"):
        cfg = compose(config_name="recognize", overrides=["pose=mediapipe_hands", f"pose.path={folders / 'detection'}",
                                                           "data.num_frames=16"])  # fmt: skip
    caplog.set_level(logging.WARNING, logger="aslexp")
    _, folder = build_or_load(tmp_path, dataset_params(cfg), root=data_root)
    first = [r.getMessage() for r in caplog.records if WARNING in r.getMessage()]
    caplog.clear()
    _, again = build_or_load(tmp_path, dataset_params(cfg), root=data_root)
    assert again == folder and len(first) == 1
    assert [r.getMessage() for r in caplog.records if WARNING in r.getMessage()] == [
        f"{first[0]} (found when this build was made)"]
