"""aslexp.quaternion.twist_angle: the turn about one axis, whatever the tilt about the others."""

from __future__ import annotations

import numpy as np
import pytest

from aslexp import quaternion


def _about(axis: int, angle: float) -> np.ndarray:
    q = np.zeros(4)
    q[0], q[1 + axis] = np.cos(angle / 2), np.sin(angle / 2)
    return q


@pytest.mark.parametrize("angle", [0.0, 0.3, -1.2, 3.0])
def test_twist_angle_reads_a_turn_about_the_axis_and_ignores_a_tilt(angle):
    reference = quaternion.multiply(_about(0, 0.4), _about(1, 0.7))  # any reference rotation
    turned = quaternion.multiply(reference, _about(1, angle))  # turned about the reference's y
    assert quaternion.twist_angle(reference, turned, 1) == pytest.approx(angle, abs=1e-9)
    assert quaternion.twist_angle(turned, reference, 1) == pytest.approx(-angle, abs=1e-9)
    tilted = quaternion.multiply(reference, _about(0, 0.25))  # a tilt about x is no turn about y
    assert quaternion.twist_angle(reference, tilted, 1) == pytest.approx(0.0, abs=1e-9)
    # Past half a turn the angle wraps into [-pi, pi); q and -q are the same rotation.
    assert quaternion.twist_angle(reference, quaternion.multiply(reference, _about(1, np.pi + 0.5)), 1) == \
        pytest.approx(-np.pi + 0.5, abs=1e-9)
    assert quaternion.twist_angle(reference, -turned, 1) == pytest.approx(angle, abs=1e-9)


def test_rotvec_is_scipys_rotation_vector_for_any_angle_and_either_sign():
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(0)
    q = quaternion.normalize(rng.normal(size=(500, 4)))
    tiny = np.concatenate([np.ones((4, 1)), 1e-5 * rng.normal(size=(4, 3))], axis=1)  # below scipy's series bound
    q = np.concatenate([q, -q, quaternion.normalize(tiny), [[1.0, 0, 0, 0], [0.0, 1, 0, 0]]])
    expected = Rotation.from_quat(q, scalar_first=True).as_rotvec()
    np.testing.assert_allclose(quaternion.rotvec(q), expected, rtol=1e-13, atol=1e-15)
    assert quaternion.rotvec(q.reshape(-1, 2, 4)).shape == (len(q) // 2, 2, 3)
