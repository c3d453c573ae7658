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
    one answers with that reference itself, so a one-motion batch pays nothing for the pool. A larger
    pool stacks all its motions' frames into one table (:class:`_StackedMotions`), so each quantity
    of a batch's rows is one vectorised lookup, whatever the number of distinct motions.
    """

    def __init__(self, references: list[ReferenceMotion]) -> None:
        if not references:
            raise ValueError("a reference pool needs at least one motion")
        widths = {r.layout.motion_columns for r in references}
        if len(widths) != 1:
            raise ValueError(f"a reference pool holds one body's motions; got widths {sorted(widths)}")
        self.references = list(references)
        self.durations = np.asarray([r.duration for r in references])
        self.stacked = _StackedMotions(self.references) if len(self.references) > 1 else None

    def __len__(self) -> int:
        return len(self.references)

    def select(self, clips: np.ndarray) -> "ReferenceMotion | _PoolRows":
        if self.stacked is None:
            return self.references[0]
        return _PoolRows(self.stacked, np.asarray(clips, dtype=int))


class _StackedMotions:
    """All frames of a pool's motions in one table, with per-motion offsets, frame counts, start
    times, durations and loop modes: :meth:`Motion.locate_many` and :meth:`Motion.sample_many` for
    rows of different motions at once, the same operations element for element (so the same numbers).
    """

    def __init__(self, references: list[ReferenceMotion]) -> None:
        motions = [r.motion for r in references]
        self.q_columns = references[0]._q_columns
        if any(not np.array_equal(r._q_columns, self.q_columns) for r in references):
            raise ValueError("a reference pool holds one body's motions; their joint columns differ")
        self.count = np.asarray([m.num_frames for m in motions])
        self.offset = np.concatenate([[0], np.cumsum(self.count)[:-1]])
        self.duration = np.asarray([m.duration for m in motions])
        self.wraps = np.asarray([m.loop == "wrap" for m in motions])
        self.still = (self.count == 1) | (self.duration <= 0)  # Motion._locate's frame 0, fraction 0
        # one spare row at the end: frame i + 1 of a one-frame last motion (read, then not used)
        frames = [m.frames for m in motions]
        self.frames = np.concatenate(frames + [frames[-1][-1:]])
        self.dt = np.concatenate([m.dt for m in motions])
        self.column_velocity = np.concatenate([r._column_velocity for r in references])
        self.joint_velocity = np.concatenate([r._joint_velocity for r in references])
        # start times, one row per motion, padded with +inf: counting the times <= t is searchsorted(right)
        self.times = np.full((len(motions), int(self.count.max())), np.inf)
        for k, m in enumerate(motions):
            self.times[k, :m.num_frames] = m.times
        # quaternion blocks nlerp'd, all at once: (blocks, 4) columns, and which motions have each
        # (a motion's own ``quaternions``; the same for all of one body's motions, as a rule)
        blocks = sorted({q for m in motions for q in m.quaternions})
        self.quaternion_columns = np.asarray([np.arange(q, q + 4) for q in blocks], dtype=int).reshape(-1, 4)
        self.has_quaternion = np.asarray([[q in m.quaternions for q in blocks] for m in motions]).reshape(len(motions), -1)
        self.all_have_quaternions = bool(self.has_quaternion.all())

    def locate(self, clips: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`Motion.locate_many` per row: rows of the stacked table (frame i of each row's motion)
        and fractions."""
        duration, count = self.duration[clips], self.count[clips]
        with np.errstate(invalid="ignore", divide="ignore"):  # still motions: overwritten below
            wrapped = np.fmod(t, duration)
            wrapped = np.where(wrapped < 0, wrapped + duration, wrapped)
            t = np.where(self.wraps[clips], wrapped, np.clip(t, 0.0, duration))
            times = self.times[clips]
            i = np.count_nonzero(times <= t[:, None], axis=1) - 1
            i = np.where(np.isnan(t), count - 1, i)  # searchsorted puts NaN after every time
            i = np.minimum(np.maximum(i, 0), count - 2)
            i = np.where(self.still[clips], 0, i)
            start = np.take_along_axis(times, i[:, None], axis=1)[:, 0]
            frac = np.clip((t - start) / self.dt[self.offset[clips] + i], 0.0, 1.0)
        frac = np.where(self.still[clips], 0.0, frac)
        return self.offset[clips] + i, frac

    def sample(self, clips: np.ndarray, row: np.ndarray, frac: np.ndarray) -> np.ndarray:
        """:meth:`Motion.sample_many` per row, (rows, D), from :meth:`locate`'s answer."""
        a, b = self.frames[row], self.frames[row + 1]
        out = a + frac[:, None] * (b - a)
        columns = self.quaternion_columns
        if len(columns):  # Motion.sample_many's nlerp, on (rows, blocks, 4) arrays
            qa, qb = a[:, columns], b[:, columns]
            qb = np.where(np.sum(qa * qb, axis=2, keepdims=True) < 0, -qb, qb)  # shortest arc
            blend = qa + frac[:, None, None] * (qb - qa)
            blend = blend / np.maximum(np.linalg.norm(blend, axis=2, keepdims=True), 1e-12)
            if not self.all_have_quaternions:
                blend = np.where(self.has_quaternion[clips][:, :, None], blend, out[:, columns])
            out[:, columns] = blend
        single = self.count[clips] == 1  # Motion.sample_many: a one-frame motion's frame as it is
        return np.where(single[:, None], a, out) if single.any() else out

    def phase(self, clips: np.ndarray, t: np.ndarray) -> np.ndarray:
        duration = self.duration[clips]
        with np.errstate(invalid="ignore", divide="ignore"):
            p = np.where(self.wraps[clips], (t / duration) % 1.0, np.clip(t / duration, 0.0, 1.0))
        return np.where(duration <= 0, 0.0, p)


class _PoolRows:
    """:class:`ReferencePool` rows: each method reads every row from its own motion in the stacked
    table, one lookup per quantity (what :class:`ReferenceMotion` gives for that motion)."""

    def __init__(self, stacked: _StackedMotions, clips: np.ndarray) -> None:
        self.stacked, self.clips, self.size = stacked, clips, len(clips)

    def _times(self, t: np.ndarray) -> np.ndarray:
        return np.broadcast_to(np.asarray(t, dtype=np.float64), (self.size,))

    def joints_many(self, t: np.ndarray) -> np.ndarray:
        row, frac = self.stacked.locate(self.clips, self._times(t))
        return self.stacked.sample(self.clips, row, frac)[:, self.stacked.q_columns]

    def joint_velocities_many(self, t: np.ndarray) -> np.ndarray:
        row, _ = self.stacked.locate(self.clips, self._times(t))
        return self.stacked.joint_velocity[row]

    def root_many(self, t: np.ndarray):
        return self.state_many(t)[2:]

    def state_many(self, t: np.ndarray):
        s = self.stacked
        row, frac = s.locate(self.clips, self._times(t))
        frame = s.sample(self.clips, row, frac)
        vel = s.column_velocity[row]
        omega = 2.0 * quaternion.multiply(vel[:, 3:7], quaternion.conjugate(frame[:, 3:7]))[:, 1:4]
        return (frame[:, s.q_columns], s.joint_velocity[row], frame[:, 0:3], frame[:, 3:7], vel[:, 0:3], omega)

    def phase_many(self, t: np.ndarray) -> np.ndarray:
        return self.stacked.phase(self.clips, self._times(t))


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
