"""A pool of reference motions read in one lookup per quantity: every row's reads are its own
motion's :class:`ReferenceMotion` reads, for real motions of different lengths, frame steps and
loop modes (the thesis' signs, a sign extracted here from a WLASL pose array, the hand letters)."""

from __future__ import annotations

import contextlib
import io

import numpy as np
import pytest

from aslexp.envs.assembly import ImitationSetup
from aslexp.sim.motion import Motion
from aslexp.sim.reference import ReferenceMotion, ReferencePool

THESIS_SIGNS = ["00433", "52861", "69318", "69546", "tuning_motion_whole"]  # 0.03 s and 1/30 s frames
LETTERS = ["A", "B", "C", "D", "E", "tuning_motion"]
QUANTITIES = ("joints_many", "joint_velocities_many", "root_many", "state_many", "phase_many")


@pytest.fixture(scope="module")
def extracted_sign(data_root, tmp_path_factory):
    """One WLASL clip extracted to an upper-body motion (0.04 s frames)."""
    from aslexp.pose.extract_cli import extract_main

    array = data_root / "keypoints" / "wlasl-mediapipe-pose" / "01457.npy"
    if not array.is_file():
        pytest.skip(f"the shared WLASL pose array {array} is not there")
    out = tmp_path_factory.mktemp("extracted")
    with contextlib.redirect_stdout(io.StringIO()):
        assert extract_main([str(array), "--motions", "--out", str(out), "--quiet"]) == 0
    found = sorted(out.rglob("upper_body/*.txt"))
    assert found, f"no upper-body motion extracted under {out}"
    return found[0]


def _variants(motion: Motion) -> list[Motion]:
    """The motion as it is, as a non-looping motion, and cut to its first frame or first two frames."""
    q = motion.quaternions
    return [motion, Motion(motion.frames, motion.dt, loop="none", quaternions=q, source="not looping"),
            Motion(motion.frames[:1], motion.dt[:1], loop=motion.loop, quaternions=q, source="one frame"),
            Motion(motion.frames[:2], motion.dt[:2], loop="none", quaternions=q, source="two frames")]


def _times(references: list[ReferenceMotion], rows: np.ndarray, rng) -> np.ndarray:
    """Per row: 0, its duration, frame starts, past the end (wrap), before 0, and random times."""
    durations = np.array([references[c].duration for c in rows])
    starts = np.array([references[c].motion.times[rng.integers(references[c].motion.num_frames)] for c in rows])
    kinds = rng.integers(6, size=len(rows))
    return np.select([kinds == 0, kinds == 1, kinds == 2, kinds == 3, kinds == 4],
                     [np.zeros(len(rows)), durations, starts, durations * rng.uniform(1.0, 3.5, len(rows)),
                      -rng.uniform(0.0, 2.0, len(rows))],
                     rng.uniform(0.0, 1.0, len(rows)) * durations)


def _assert_rows_read_their_own_motions(references: list[ReferenceMotion], seed: int) -> None:
    pool = ReferencePool(references)
    rng = np.random.default_rng(seed)
    for _ in range(20):
        rows = rng.integers(len(references), size=32)
        t = _times(references, rows, rng)
        view = pool.select(rows)
        for name in QUANTITIES:
            answer = getattr(view, name)(t)
            parts = answer if isinstance(answer, tuple) else (answer,)
            for k, (row, time) in enumerate(zip(rows, t)):
                own = getattr(references[row], name)(np.array([time]))
                for part, expected in zip(parts, own if isinstance(own, tuple) else (own,)):
                    np.testing.assert_array_equal(part[k], expected[0], err_msg=f"{name}, motion {row}, t={time!r}")


def test_a_pool_of_signs_reads_each_rows_own_motion(data_root, extracted_sign):
    setup = ImitationSetup.from_groups(THESIS_SIGNS[0], body="upper_body", data_root=data_root)
    folder = data_root / "motions" / "upper_body"
    motions = [setup.load_motion(folder / f"{m}.txt") for m in THESIS_SIGNS] + [setup.load_motion(extracted_sign)]
    steps = {round(float(m.dt[0]), 4) for m in motions}
    assert len(steps) >= 3 and len({m.num_frames for m in motions}) == len(motions)  # 0.03, 1/30, 0.04 s
    assert all(len(m.quaternions) > 1 for m in motions)  # the spherical joints, nlerp'd
    references = [ReferenceMotion(m, setup.layout) for m in motions]
    references += [ReferenceMotion(v, setup.layout) for v in _variants(motions[1])]
    _assert_rows_read_their_own_motions(references, seed=0)


def test_a_pool_of_hand_letters_reads_each_rows_own_motion(data_root):
    setup = ImitationSetup.from_groups("A", engine="mujoco", data_root=data_root)
    folder = data_root / "motions" / "hand"
    references = [ReferenceMotion(setup.load_motion(folder / f"{m}.txt"), setup.layout) for m in LETTERS]
    letter = references[2].motion
    references += [ReferenceMotion(v, setup.layout) for v in _variants(letter)]
    # a motion whose root rotation is read by plain lerp, among nlerp'd ones: each row as its motion says
    references.append(ReferenceMotion(Motion(letter.frames, letter.dt, quaternions=(), source="lerp"), setup.layout))
    _assert_rows_read_their_own_motions(references, seed=1)


def test_a_pool_of_one_is_the_reference_and_rows_of_one_motion_read_it(data_root):
    setup = ImitationSetup.from_groups("A", engine="mujoco", data_root=data_root)
    only = ReferenceMotion(setup.load_motion("A"), setup.layout)
    assert ReferencePool([only]).select(np.zeros(4, dtype=int)) is only  # the single env's path
    other = ReferenceMotion(setup.load_motion("B"), setup.layout)
    t = np.array([0.0, only.duration, 2.5 * only.duration, 0.37])
    view = ReferencePool([other, only]).select(np.ones(4, dtype=int))
    for part, expected in zip(view.state_many(t), only.state_many(t)):
        np.testing.assert_array_equal(part, expected)
    np.testing.assert_array_equal(view.phase_many(0.2), only.phase_many(np.full(4, 0.2)))  # one time for all rows
