"""Quaternions (w, x, y, z), one module for the whole package: simulation, environments,
retargeting and reports import from here (it imports nothing of aslexp, so any layer may).

Conversions go through scipy's :class:`~scipy.spatial.transform.Rotation`. Four functions run
on every environment step and are written out in numpy instead, because scipy's object set-up
dominates on arrays of 2-40 quaternions. Measured here (shared 2-core machine, best of 10 x
2,000 calls, ``python -m aslexp.quaternion``): rotating 2 tip offsets 15 us (scipy 39 us), the angle between
4 pairs 23 us (scipy 54 us), multiplying 39 link rotations 22 us (scipy 85 us).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

IDENTITY = np.array([1.0, 0.0, 0.0, 0.0])
_CONJUGATE = np.array([1.0, -1.0, -1.0, -1.0])


def normalize(q: np.ndarray) -> np.ndarray:
    """Unit quaternions along the last axis."""
    q = np.asarray(q, dtype=np.float64)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def conjugate(q: np.ndarray) -> np.ndarray:
    """Conjugates (inverse rotations of unit quaternions) along the last axis."""
    return np.asarray(q, dtype=np.float64) * _CONJUGATE


def multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a * b; broadcasts over leading axes (hot path: written out, see above)."""
    a, b = np.asarray(a), np.asarray(b)
    aw, ax, ay, az = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bw, bx, by, bz = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    return np.stack([
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ], axis=-1)


def rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vector(s) v by unit quaternion(s) q; broadcasts over rows (hot path, see above).

    v' = v + w t + u x t with t = 2 u x v (u the vector part).
    """
    q = np.asarray(q, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    vx, vy, vz = v[..., 0], v[..., 1], v[..., 2]
    tx, ty, tz = 2 * (y * vz - z * vy), 2 * (z * vx - x * vz), 2 * (x * vy - y * vx)
    return np.stack([vx + w * tx + (y * tz - z * ty),
                     vy + w * ty + (z * tx - x * tz),
                     vz + w * tz + (x * ty - y * tx)], axis=-1)


def angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rotation angle in [0, pi] of the difference between the rotations a and b (hot path)."""
    dot = np.abs(np.sum(normalize(a) * normalize(b), axis=-1))
    return 2.0 * np.arccos(np.clip(dot, 0.0, 1.0))


def twist_angle(a: np.ndarray, b: np.ndarray, axis: int) -> float:
    """The angle (rad, in [-pi, pi)) by which b is turned from a about a's coordinate axis ``axis``
    (0 x, 1 y, 2 z): the twist of conj(a) * b (e.g. a body's yaw against its reference's)."""
    relative = multiply(conjugate(np.asarray(a, dtype=np.float64)), np.asarray(b, dtype=np.float64))
    turn = 2.0 * np.arctan2(relative[1 + axis], relative[0])
    return float((turn + np.pi) % (2.0 * np.pi) - np.pi)


def to_matrix(q: np.ndarray) -> np.ndarray:
    """(..., 4) -> (..., 3, 3) rotation matrices."""
    q = np.asarray(q, dtype=np.float64)
    return Rotation.from_quat(q.reshape(-1, 4), scalar_first=True).as_matrix().reshape(*q.shape[:-1], 3, 3)


def matrices(q: np.ndarray) -> np.ndarray:
    """(..., 4) unit quaternions -> (..., 3, 3) rotation matrices, written out (no scipy round trip:
    the batched observation turns N frames at every step)."""
    q = np.asarray(q, dtype=np.float64)
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    xx, yy, zz, xy, xz, yz, wx, wy, wz = x * x, y * y, z * z, x * y, x * z, y * z, w * x, w * y, w * z
    return np.stack([1 - 2 * (yy + zz), 2 * (xy - wz), 2 * (xz + wy),
                     2 * (xy + wz), 1 - 2 * (xx + zz), 2 * (yz - wx),
                     2 * (xz - wy), 2 * (yz + wx), 1 - 2 * (xx + yy)], axis=-1).reshape(*q.shape[:-1], 3, 3)


def from_matrix(m: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotations -> (..., 4) quaternions with w >= 0."""
    m = np.asarray(m, dtype=np.float64)
    q = Rotation.from_matrix(m.reshape(-1, 3, 3)).as_quat(scalar_first=True, canonical=True)
    return q.reshape(*m.shape[:-2], 4)


def rotvec(q: np.ndarray) -> np.ndarray:
    """(..., 4) unit quaternions -> (..., 3) rotation vectors (axis * angle, the shortest arc), as
    scipy's ``as_rotvec`` computes them (hot path: the batched PD's ball-joint targets every step)."""
    q = np.asarray(q, dtype=np.float64)
    q = np.where(q[..., :1] < 0, -q, q)
    vector = q[..., 1:]
    angle = 2.0 * np.arctan2(np.linalg.norm(vector, axis=-1), q[..., 0])
    small = angle <= 1e-3  # scipy's series below it
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.where(small, 2.0 + angle * angle / 12.0 + 7.0 * angle ** 4 / 2880.0, angle / np.sin(angle / 2.0))
    return scale[..., None] * vector


def relative_rotvec(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Rotation vectors (axis * angle, shortest arc) of conj(a) * b: the rotation from a to b in
    a's own frame; (..., 4) each -> (..., 3)."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    shape = np.broadcast_shapes(a.shape, b.shape)[:-1]
    rel = Rotation.from_quat(conjugate(a).reshape(-1, 4), scalar_first=True) * \
        Rotation.from_quat(np.broadcast_to(b, (*shape, 4)).reshape(-1, 4), scalar_first=True)
    return rel.as_rotvec().reshape(*shape, 3)


def z_to(direction) -> list[float]:
    """The rotation (w x y z) turning +z onto the unit vector ``direction`` (a ground plane's normal)."""
    direction = np.asarray(direction, dtype=np.float64)
    axis, cos = np.cross([0.0, 0.0, 1.0], direction), float(direction[2])
    if np.linalg.norm(axis) < 1e-9:
        return [1.0, 0.0, 0.0, 0.0] if cos > 0 else [0.0, 1.0, 0.0, 0.0]
    half = np.arccos(np.clip(cos, -1.0, 1.0)) / 2
    axis = axis / np.linalg.norm(axis) * np.sin(half)
    return [float(np.cos(half)), *axis.tolist()]


def wxyz_to_xyzw(q) -> list[float]:
    """The scalar-last order (x, y, z, w) of one quaternion."""
    return [float(q[1]), float(q[2]), float(q[3]), float(q[0])]


if __name__ == "__main__":  # the timings quoted in the module docstring
    import timeit

    rng = np.random.default_rng(0)
    two, many = normalize(rng.normal(size=(2, 4))), normalize(rng.normal(size=(39, 4)))
    cases = {
        "rotate 2 offsets": (lambda: rotate(two, [0.0, 0.0, 0.04]),
                             lambda: Rotation.from_quat(two, scalar_first=True).apply([0.0, 0.0, 0.04])),
        "angle of 4 pairs": (lambda: angle(many[:4], many[4:8]),
                             lambda: (Rotation.from_quat(many[:4], scalar_first=True).inv()
                                      * Rotation.from_quat(many[4:8], scalar_first=True)).magnitude()),
        "multiply 39": (lambda: multiply(conjugate(many[0]), many),
                        lambda: (Rotation.from_quat(many[0], scalar_first=True).inv()
                                 * Rotation.from_quat(many, scalar_first=True)).as_quat(scalar_first=True)),
    }
    for name, (ours, scipy_version) in cases.items():
        times = [min(timeit.repeat(f, number=2000, repeat=10)) / 2000 * 1e6 for f in (ours, scipy_version)]
        print(f"{name}: numpy {times[0]:.1f} us, scipy {times[1]:.1f} us")
