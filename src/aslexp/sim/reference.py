"""A motion read through a body's layout: reference joint positions and velocities at any time."""

from __future__ import annotations

import numpy as np

from aslexp.sim.body import BodyLayout
from aslexp.sim.motion import Motion
from aslexp.sim.world import quat_conjugate, quat_multiply


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

    @property
    def duration(self) -> float:
        return self.motion.duration

    def phase(self, t: float) -> float:
        return self.motion.phase(t)

    def joints(self, t: float) -> np.ndarray:
        """Joint positions at time t (motion layout, quaternions w x y z)."""
        return self.motion.sample(t)[self._q_columns]

    def joint_velocities(self, t: float) -> np.ndarray:
        """Joint velocities at time t (1 per revolute joint, 3 per spherical joint)."""
        i, _ = self.motion._locate(t)
        column_velocity = self._column_velocity[i]
        if self.layout.all_revolute:
            return column_velocity[self._q_columns]
        frame = self.motion.sample(t)
        out = []
        for joint in self.layout.joints:
            c = joint.motion_column
            if joint.dof == 1:
                out.append(column_velocity[c])
            else:
                # omega = 2 * (dq/dt) * conj(q), vector part (world-in-parent frame convention).
                omega = 2.0 * quat_multiply(column_velocity[c:c + 4], quat_conjugate(frame[c:c + 4]))
                out.extend(omega[1:4])
        return np.asarray(out, dtype=np.float64)

    def root(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Root position, rotation (w x y z), linear and angular velocity at time t."""
        frame = self.motion.sample(t)
        i, _ = self.motion._locate(t)
        vel = self._column_velocity[i]
        omega = 2.0 * quat_multiply(vel[3:7], quat_conjugate(frame[3:7]))[1:4]
        return frame[0:3].copy(), frame[3:7].copy(), vel[0:3].copy(), omega
