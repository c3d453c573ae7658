"""A motion read through a body's layout: reference joint positions and velocities at any time."""

from __future__ import annotations

import numpy as np

from aslexp.sim.body import BodyLayout
from aslexp.sim.motion import Motion
from aslexp import quaternion


class ReferenceMotion:
    """Joint-space view of a :class:`Motion` for one body.

    Joint velocities follow the state layout: 1 value per revolute joint, 3 (angular velocity,
    from the quaternion finite difference) per spherical joint. The root follows the motion's
    first 7 columns; its velocities come from the same finite differences.
    """

    def __init__(self, motion: Motion, layout: BodyLayout) -> None:
        if motion.num_columns != layout.motion_columns:
            raise ValueError(
                f"{motion.source or 'motion'}: {motion.num_columns} values per frame, the body expects "
                f"{layout.motion_columns}"
            )
        self.motion = motion
        self.layout = layout
        self._q_columns = np.concatenate([
            np.arange(j.motion_column, j.motion_column + j.dof) for j in layout.joints
        ]).astype(int)
        self._column_velocity = motion.velocities()
        self._joint_velocity = self._joint_velocity_table()

    @property
    def duration(self) -> float:
        return self.motion.duration

    def phase(self, t: float) -> float:
        return self.motion.phase(t)

    def phase_many(self, t: np.ndarray) -> np.ndarray:
        return self.motion.phase_many(t)

    def joints(self, t: float) -> np.ndarray:
        """Joint positions at time t (motion layout, quaternions w x y z)."""
        return self.motion.sample(t)[self._q_columns]

    def joint_velocities(self, t: float) -> np.ndarray:
        """Joint velocities at time t (1 per revolute joint, 3 per spherical joint).

        Constant over each frame interval (forward differences, as :meth:`Motion.velocities`);
        a spherical joint's is the angular velocity in the joint's child frame, as PyBullet reads
        and writes it (``getJointStateMultiDof``): log(conj(q_i) q_i+1) / dt_i.
        """
        i, _ = self.motion._locate(t)
        return self._joint_velocity[i].copy()

    # -- many times at once (the batched environments) -----------------------------------------------
    def joints_many(self, t: np.ndarray) -> np.ndarray:
        """(len(t), layout) joint positions at the times ``t``."""
        return self.motion.sample_many(t)[:, self._q_columns]

    def joint_velocities_many(self, t: np.ndarray) -> np.ndarray:
        """(len(t), velocity layout) joint velocities at the times ``t``."""
        i, _ = self.motion.locate_many(t)
        return self._joint_velocity[i]

    def root_many(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`root` at the times ``t``: (len(t), 3), (len(t), 4), (len(t), 3), (len(t), 3)."""
        return self.state_many(t)[2:]

    def state_many(self, t: np.ndarray) -> tuple[np.ndarray, ...]:
        """Joint positions and velocities and the root (position, rotation, linear and angular
        velocity) at the times ``t``, from one interpolation: what a batched step compares with."""
        located = self.motion.locate_many(t)
        frame = self.motion.sample_many(t, located)
        i = located[0]
        vel = self._column_velocity[i]
        omega = 2.0 * quaternion.multiply(vel[:, 3:7], quaternion.conjugate(frame[:, 3:7]))[:, 1:4]
        return (frame[:, self._q_columns], self._joint_velocity[i], frame[:, 0:3], frame[:, 3:7], vel[:, 0:3], omega)

    def _joint_velocity_table(self) -> np.ndarray:
        motion, layout = self.motion, self.layout
        table = []
        for joint in layout.joints:
            c = joint.motion_column
            if joint.dof == 1:
                table.append(self._column_velocity[:, c:c + 1])
            else:
                table.append(_local_angular_velocity(motion.frames[:, c:c + 4], motion.dt, motion.loop))
        return np.ascontiguousarray(np.concatenate(table, axis=1))

    def root(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Root position, rotation (w x y z), linear and angular velocity at time t."""
        frame = self.motion.sample(t)
        i, _ = self.motion._locate(t)
        vel = self._column_velocity[i]
        omega = 2.0 * quaternion.multiply(vel[3:7], quaternion.conjugate(frame[3:7]))[1:4]
        return frame[0:3].copy(), frame[3:7].copy(), vel[0:3].copy(), omega


class ReferencePool:
    """Several references of one body, one per row of a batch (one policy, many motions).

    ``select(clips)`` is what a batch's rows read: an object with :class:`ReferenceMotion`'s
    ``*_many`` methods, whose ``i``-th time is read from the reference ``clips[i]`` names. A pool of
    one answers with that reference itself, so a one-motion batch pays nothing for the pool.
    """

    def __init__(self, references: list[ReferenceMotion]) -> None:
        if not references:
            raise ValueError("a reference pool needs at least one motion")
        widths = {r.layout.motion_columns for r in references}
        if len(widths) != 1:
            raise ValueError(f"a reference pool holds one body's motions; got widths {sorted(widths)}")
        self.references = list(references)
        self.durations = np.asarray([r.duration for r in references])

    def __len__(self) -> int:
        return len(self.references)

    def select(self, clips: np.ndarray) -> "ReferenceMotion | _PoolRows":
        if len(self.references) == 1:
            return self.references[0]
        return _PoolRows(self.references, np.asarray(clips, dtype=int))


class _PoolRows:
    """:class:`ReferencePool` rows: each method reads every reference on its own rows (a row of ``t``
    per clip) and puts the answers back in row order."""

    def __init__(self, references: list[ReferenceMotion], clips: np.ndarray) -> None:
        self.groups = [(references[c], np.flatnonzero(clips == c)) for c in np.unique(clips)]
        self.size = len(clips)

    def _gather(self, method: str, t: np.ndarray):
        t = np.broadcast_to(np.asarray(t, dtype=np.float64), (self.size,))
        if len(self.groups) == 1:
            return getattr(self.groups[0][0], method)(t)
        out = None
        for reference, rows in self.groups:
            answer = getattr(reference, method)(t[rows])
            parts = answer if isinstance(answer, tuple) else (answer,)
            if out is None:
                out = tuple(np.empty((self.size,) + p.shape[1:], p.dtype) for p in parts)
            for whole, part in zip(out, parts):
                whole[rows] = part
        return out if isinstance(answer, tuple) else out[0]

    def joints_many(self, t: np.ndarray) -> np.ndarray:
        return self._gather("joints_many", t)

    def joint_velocities_many(self, t: np.ndarray) -> np.ndarray:
        return self._gather("joint_velocities_many", t)

    def root_many(self, t: np.ndarray):
        return self._gather("root_many", t)

    def state_many(self, t: np.ndarray):
        return self._gather("state_many", t)

    def phase_many(self, t: np.ndarray) -> np.ndarray:
        return self._gather("phase_many", t)


def _local_angular_velocity(q: np.ndarray, dt: np.ndarray, loop: str) -> np.ndarray:
    """(F, 3) angular velocities, child frame, of the quaternion track ``q`` (F, 4; w x y z).

    Frame i gets the rotation from q_i to q_i+1 (shortest arc) as axis * angle / dt_i; the last
    frame repeats frame 0 (looping) or its predecessor, like :meth:`Motion.velocities`.
    """
    if len(q) == 1:
        return np.zeros((1, 3))
    omega = np.empty((len(q), 3))
    omega[:-1] = quaternion.relative_rotvec(q[:-1], q[1:]) / dt[:-1, None]
    omega[-1] = omega[0] if loop == "wrap" else omega[-2]
    return omega
