"""Motion files: reading, writing, interpolation, velocities and validation."""

from __future__ import annotations

import json

import numpy as np
import pytest

from aslexp.sim.motion import Motion, MotionFormatError, load_motion, random_motion, save_motion


def test_real_motion_round_trip(tmp_path, motion_a):
    motion = load_motion(motion_a, expected_columns=22)
    assert motion.num_frames == 41 and motion.num_columns == 22 and motion.loop == "wrap"
    assert motion.duration == pytest.approx(40 * 0.03)
    copy = load_motion(save_motion(motion, tmp_path / "A.txt"))
    np.testing.assert_array_equal(copy.frames, motion.frames)
    np.testing.assert_array_equal(copy.dt, motion.dt)
    raw = json.loads(motion_a.read_text())
    assert json.loads((tmp_path / "A.txt").read_text())["Frames"][3] == pytest.approx(raw["Frames"][3])


def test_sample_interpolates_and_wraps():
    frames = np.array([[0.0, 0.9, 0.0, 1, 0, 0, 0, 0.0],
                       [0.0, 0.9, 0.0, 1, 0, 0, 0, 1.0],
                       [0.0, 0.9, 0.0, 1, 0, 0, 0, 0.0]])
    motion = Motion(frames, 0.5, loop="wrap")
    assert motion.duration == 1.0
    assert motion.sample(0.25)[7] == pytest.approx(0.5)
    assert motion.sample(0.5)[7] == pytest.approx(1.0)
    assert motion.sample(1.25)[7] == pytest.approx(0.5)  # wrapped
    assert motion.sample(-0.25)[7] == pytest.approx(0.5)
    assert motion.phase(1.25) == pytest.approx(0.25)
    clamped = Motion(frames, 0.5, loop="none")
    assert clamped.sample(5.0)[7] == pytest.approx(0.0) and clamped.sample(-1)[7] == 0.0
    np.testing.assert_allclose(motion.sample(0.3)[3:7], [1, 0, 0, 0])


def test_velocities_are_finite_differences():
    frames = np.zeros((3, 8))
    frames[:, 3] = 1
    frames[:, 7] = [0.0, 0.3, 0.9]
    motion = Motion(frames, [0.1, 0.2, 0.2], loop="none")
    np.testing.assert_allclose(motion.velocities()[:, 7], [3.0, 3.0, 3.0])
    assert motion.sample_velocity(0.05)[7] == pytest.approx(3.0)
    looped = Motion(frames, [0.1, 0.3, 0.1], loop="wrap")
    np.testing.assert_allclose(looped.velocities()[:, 7], [3.0, 2.0, 3.0])


def _write(path, payload):
    path.write_text(json.dumps(payload))
    return path


def test_wrong_column_count_names_expected_and_found(tmp_path, motion_a):
    with pytest.raises(MotionFormatError) as err:
        load_motion(motion_a, expected_columns=30)
    assert "30" in str(err.value) and "22" in str(err.value) and "A.txt" in str(err.value)


@pytest.mark.parametrize("payload, match", [
    ({"Loop": "wrap", "Frames": [[0.03, 0, 0.9, 0, 1, 0, 0, 0, float("nan")]] * 2}, "non-finite"),
    ({"Loop": "wrap", "Frames": [[0.0, 0, 0.9, 0, 1, 0, 0, 0, 0.1]] * 2}, "dt > 0"),
    # a 1e9 joint angle was accepted
    ({"Loop": "wrap", "Frames": [[0.03, 0, 0.9, 0, 1, 0, 0, 0, 0.1], [0.03, 0, 0.9, 0, 1, 0, 0, 0, 1e9]]},
     r"frame 1, value 8 after dt is 1e\+09 \(1 such values\); expected numbers of magnitude at most 1,000"),
    ({"Loop": "sometimes", "Frames": [[0.03, 0, 0.9, 0, 1, 0, 0, 0, 0.1]] * 2}, "Loop"),
    ({"Loop": "wrap", "Frames": [[0.03, 0, 0.9], [0.03, 0]]}, "different lengths"),
    ({"Loop": "wrap", "Frames": []}, "non-empty"),
    ({"Loop": "wrap"}, "Frames"),
])
def test_invalid_files_are_refused(tmp_path, payload, match):
    path = tmp_path / "bad.txt"
    path.write_text(json.dumps(payload).replace("NaN", "NaN"))
    with pytest.raises(MotionFormatError, match=match):
        load_motion(path)


def test_missing_and_garbled_files(tmp_path):
    with pytest.raises(FileNotFoundError):
        load_motion(tmp_path / "none.txt")
    (tmp_path / "garbled.txt").write_text("{not json")
    with pytest.raises(MotionFormatError, match="not valid JSON"):
        load_motion(tmp_path / "garbled.txt")


def test_random_motion_stays_within_limits():
    motion = random_motion([0.0] * 15, [2.0] * 15, seconds=2.0, seed=3)
    joints = motion.frames[:, 7:]
    assert motion.num_columns == 22 and joints.min() >= 0.0 and joints.max() <= 2.0
    assert np.abs(np.diff(joints, axis=0)).max() < 0.5  # smooth
