"""Reference motions in the DeepMimic text format (JSON).

File: ``{"Loop": "wrap" | "none", "Frames": [[dt, root_x, root_y, root_z, root_qw, root_qx,
root_qy, root_qz, joint values...], ...]}``. Each frame's first value is its own duration; as in
DeepMimic, the motion lasts the sum of the durations of all frames but the last (the last frame
is the end pose, which a looping motion shares with its first).

In memory a :class:`Motion` holds the frames WITHOUT the dt column, ``frames[:, 0:3]`` the root
position, ``frames[:, 3:7]`` the root quaternion (w, x, y, z), the rest the joint values in the
body's order (1 value per revolute joint, 4 (w, x, y, z) per spherical joint).
"""

from __future__ import annotations

import json
import logging
import math
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from aslexp.errors import DataError
from aslexp.files import atomic_path

log = logging.getLogger("aslexp.motion")
LOOP_MODES = ("wrap", "none")
MAX_MOTION_VALUE = 1000.0  # larger in magnitude: a broken file (load_motion refuses it)
ROOT_COLUMNS = 7  # root position (3) + root quaternion (4)
QUATERNION_TOLERANCE = 0.5  # |norm - 1| above this: not a unit quaternion (DeepMimic's own files reach 0.42)
# Plausible frame durations (s): 240 fps to 10 fps. The thesis' clips use 0.03-0.033 s; one outside
# this range is usually in other units (milliseconds, or a frame count), and it runs, slowed or sped up.
PLAUSIBLE_FRAME_DURATION = (1.0 / 240.0, 0.1)


class MotionFormatError(DataError):
    """A motion file or array that does not follow the format (the message names file and field).

    ``found``: the values per frame the file has, when the width was what did not fit."""

    def __init__(self, message: str, found: int | None = None) -> None:
        super().__init__(message)
        self.found = found


class Motion:
    """A reference motion: frames (F, D) without the dt column, per-frame durations, loop mode.

    ``quaternions`` lists the first column of each (w, x, y, z) block, interpolated by
    normalised linear interpolation instead of plain lerp (default: the root rotation, column 3).
    """

    def __init__(
        self,
        frames: np.ndarray,
        dt: np.ndarray | float,
        loop: str = "wrap",
        quaternions: Sequence[int] | None = None,
        source: str | None = None,
    ) -> None:
        where = source or "motion"
        frames = np.asarray(frames, dtype=np.float64)
        if frames.ndim != 2 or frames.shape[0] < 1:
            raise MotionFormatError(f"{where}: Frames must be a non-empty 2-D array, got shape {frames.shape}")
        dt_arr = np.broadcast_to(np.asarray(dt, dtype=np.float64), (frames.shape[0],)).copy()
        if loop not in LOOP_MODES:
            raise MotionFormatError(f"{where}: Loop must be one of {LOOP_MODES}, got {loop!r}")
        if not np.all(np.isfinite(frames)):
            bad = np.argwhere(~np.isfinite(frames))[0]
            raise MotionFormatError(
                f"{where}: non-finite value in Frames at frame {bad[0]}, column {bad[1] + 1} "
                f"(counting dt as column 0)"
            )
        if not np.all(np.isfinite(dt_arr)) or np.any(dt_arr[: max(len(dt_arr) - 1, 1)] <= 0):
            bad = int(np.argmax(~(np.isfinite(dt_arr) & (dt_arr > 0))))
            raise MotionFormatError(f"{where}: frame {bad} has duration dt={float(dt_arr[bad])!r}; "
                                    f"expected a finite dt > 0 (seconds)")
        self.frames = frames
        self.dt = dt_arr
        self.loop = loop
        self.source = source
        default_quats = (3,) if frames.shape[1] >= ROOT_COLUMNS else ()
        self.quaternions = tuple(default_quats if quaternions is None else quaternions)
        for q in self.quaternions:
            # A quaternion block must be a unit quaternion (w x y z). Near-unit ones (rounding; some
            # of DeepMimic's own files reach norm 0.93) are normalised, and counted in the log.
            norms = np.linalg.norm(frames[:, q:q + 4], axis=1)
            bad = np.flatnonzero(np.abs(norms - 1.0) > QUATERNION_TOLERANCE)
            if len(bad):
                raise MotionFormatError(
                    f"{where}: quaternion (w x y z) in columns {q + 1}-{q + 4} (counting dt as column 0) "
                    f"is not a unit quaternion in {len(bad)} frame(s), first frame {bad[0]} with norm "
                    f"{norms[bad[0]]:.4g}; expected norm 1 (+-{QUATERNION_TOLERANCE})"
                )
            off = np.abs(norms - 1.0) > 1e-3
            if np.any(off):
                log.info("%s: normalised the quaternion in columns %d-%d in %d of %d frames (norms %.3f-%.3f)",
                         where, q + 1, q + 4, int(off.sum()), len(norms), norms.min(), norms.max())
                frames = frames.copy() if frames is self.frames else frames
                frames[:, q:q + 4] /= norms[:, None]
        self.frames = frames
        # Start time of every frame; the last frame starts at `duration`.
        self.times = np.concatenate([[0.0], np.cumsum(self.dt[:-1])])

    # -- shape -----------------------------------------------------------------------------
    @property
    def num_frames(self) -> int:
        return self.frames.shape[0]

    @property
    def num_columns(self) -> int:
        """Values per frame, without the dt column."""
        return self.frames.shape[1]

    @property
    def duration(self) -> float:
        """Length of one cycle in seconds (sum of all durations but the last frame's)."""
        return float(self.times[-1])

    # -- time ------------------------------------------------------------------------------
    def _locate(self, t: float) -> tuple[int, float]:
        """Frame index i and fraction in [0, 1) so that t lies between frame i and i + 1."""
        if self.num_frames == 1 or self.duration <= 0:
            return 0, 0.0
        if self.loop == "wrap":
            t = math.fmod(t, self.duration)
            if t < 0:
                t += self.duration
        else:
            t = min(max(t, 0.0), self.duration)
        i = int(np.searchsorted(self.times, t, side="right") - 1)
        i = min(max(i, 0), self.num_frames - 2)
        frac = (t - self.times[i]) / self.dt[i]
        return i, float(min(max(frac, 0.0), 1.0))

    def locate_many(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`_locate` for an array of times: frame indices and fractions."""
        t = np.asarray(t, dtype=np.float64)
        if self.num_frames == 1 or self.duration <= 0:
            return np.zeros(t.shape, dtype=int), np.zeros(t.shape)
        if self.loop == "wrap":
            t = np.fmod(t, self.duration)
            t = np.where(t < 0, t + self.duration, t)
        else:
            t = np.clip(t, 0.0, self.duration)
        i = np.clip(np.searchsorted(self.times, t, side="right") - 1, 0, self.num_frames - 2)
        return i, np.clip((t - self.times[i]) / self.dt[i], 0.0, 1.0)

    def sample_many(self, t: np.ndarray, located: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
        """:meth:`sample` for an array of times, (len(t), D) (``located``: :meth:`locate_many`'s
        answer for ``t``, when the caller has it)."""
        i, frac = located if located is not None else self.locate_many(t)
        if self.num_frames == 1:
            return np.repeat(self.frames[:1], len(i), axis=0)
        a, b = self.frames[i], self.frames[i + 1]
        out = a + frac[:, None] * (b - a)
        for q in self.quaternions:
            qa, qb = a[:, q:q + 4], b[:, q:q + 4]
            qb = np.where(np.sum(qa * qb, axis=1, keepdims=True) < 0, -qb, qb)  # shortest arc
            blend = qa + frac[:, None] * (qb - qa)
            out[:, q:q + 4] = blend / np.maximum(np.linalg.norm(blend, axis=1, keepdims=True), 1e-12)
        return out

    def phase_many(self, t: np.ndarray) -> np.ndarray:
        """:meth:`phase` for an array of times."""
        t = np.asarray(t, dtype=np.float64)
        if self.duration <= 0:
            return np.zeros(t.shape)
        return (t / self.duration) % 1.0 if self.loop == "wrap" else np.clip(t / self.duration, 0.0, 1.0)

    def phase(self, t: float) -> float:
        """Position in the cycle, in [0, 1)."""
        if self.duration <= 0:
            return 0.0
        p = (t / self.duration) % 1.0 if self.loop == "wrap" else min(max(t / self.duration, 0.0), 1.0)
        return float(p)

    def sample(self, t: float) -> np.ndarray:
        """The frame at time ``t`` (seconds), linearly interpolated; quaternions nlerp'd."""
        # An environment step asks for the same few times several times (targets, reward,
        # observation): a small cache of the last frames (a copy is returned, the cache stays).
        cache = self.__dict__.setdefault("_sample_cache", {})
        hit = cache.get(t)
        if hit is not None:
            return hit.copy()
        out = self._sample(t)
        if len(cache) >= 8:
            cache.pop(next(iter(cache)))
        cache[t] = out
        return out.copy()

    def _sample(self, t: float) -> np.ndarray:
        i, frac = self._locate(t)
        if self.num_frames == 1:
            return self.frames[0].copy()
        a, b = self.frames[i], self.frames[i + 1]
        out = a + frac * (b - a)
        for q in self.quaternions:
            qa, qb = a[q:q + 4], b[q:q + 4]
            if np.dot(qa, qb) < 0:  # shortest arc
                qb = -qb
            blend = qa + frac * (qb - qa)
            out[q:q + 4] = blend / max(np.linalg.norm(blend), 1e-12)
        return out

    def velocities(self) -> np.ndarray:
        """Per-frame column velocities by forward finite differences, shape (F, D).

        Frame i gets (frame[i + 1] - frame[i]) / dt[i]; the last frame gets frame 0's velocity
        for a looping motion (it is where the cycle restarts) and its predecessor's otherwise.
        Quaternion blocks are differenced like other columns (the body layer converts them).
        """
        if self.num_frames == 1:
            return np.zeros_like(self.frames)
        vel = np.empty_like(self.frames)
        vel[:-1] = np.diff(self.frames, axis=0) / self.dt[:-1, None]
        vel[-1] = vel[0] if self.loop == "wrap" else vel[-2]
        return vel

    def sample_velocity(self, t: float) -> np.ndarray:
        """Column velocity at time ``t``: the slope of the interpolation segment holding ``t``."""
        i, _ = self._locate(t)
        return self.velocities()[i] if self.num_frames > 1 else np.zeros(self.num_columns)

    # -- I/O -------------------------------------------------------------------------------
    def to_dict(self) -> dict:
        rows = np.concatenate([self.dt[:, None], self.frames], axis=1)
        return {"Loop": self.loop, "Frames": rows.tolist()}

    def save(self, path: str | os.PathLike) -> Path:
        """Write the motion as DeepMimic JSON (atomically)."""
        return save_motion(self, path)

    def __repr__(self) -> str:
        return (f"Motion({self.source or '<memory>'}: {self.num_frames} frames x {self.num_columns} "
                f"values, {self.duration:.3f} s, loop={self.loop})")


def save_motion(motion: Motion, path: str | os.PathLike) -> Path:
    """Write ``motion`` to ``path`` in the DeepMimic JSON format; returns the path."""
    path = Path(path)
    with atomic_path(path) as tmp, open(tmp, "w", encoding="utf-8") as fh:
        json.dump(motion.to_dict(), fh)
    return path


def load_motion(
    path: str | os.PathLike,
    expected_columns: int | None = None,
    quaternions: Sequence[int] | None = None,
) -> Motion:
    """Read a DeepMimic motion file.

    ``expected_columns`` is the number of values per frame the model needs, WITHOUT the dt column
    (7 root values + the joint values: 22 for the 15-DoF hand); a mismatch raises
    :class:`MotionFormatError` naming the file, the expected and the found count.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"motion file not found: {path}")
    try:
        with open(path, encoding="utf-8") as fh:
            payload = json.load(fh)
    except json.JSONDecodeError as exc:
        raise MotionFormatError(f"{path}: not valid JSON ({exc})") from exc
    if not isinstance(payload, dict) or "Frames" not in payload:
        raise MotionFormatError(f"{path}: expected a JSON object with a 'Frames' list")
    rows = payload["Frames"]
    if not isinstance(rows, list) or not rows:
        raise MotionFormatError(f"{path}: 'Frames' must be a non-empty list of frames")
    widths = {len(r) if isinstance(r, list) else -1 for r in rows}
    if len(widths) != 1 or -1 in widths:
        raise MotionFormatError(f"{path}: frames have different lengths {sorted(widths)}; expected one width")
    try:
        data = np.asarray(rows, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise MotionFormatError(f"{path}: 'Frames' holds non-numeric values ({exc})") from exc
    if data.shape[1] < 2:
        raise MotionFormatError(f"{path}: frames need a dt column and at least one value")
    # Angles in radians, root positions in metres, quaternion parts within 1: a value beyond 1,000 in
    # magnitude is a broken file, and a simulation driven by it would blow up (non-finite: Motion says).
    bad = np.isfinite(data) & (np.abs(data) > MAX_MOTION_VALUE)
    if bad.any():
        frame, column = (int(i) for i in np.argwhere(bad)[0])
        what = "dt (s)" if column == 0 else f"value {column} after dt"
        raise MotionFormatError(f"{path}: frame {frame}, {what} is {data[frame, column]:.6g} ({int(bad.sum())} such "
                                f"values); expected numbers of magnitude at most {MAX_MOTION_VALUE:,.0f} "
                                f"(radians, metres, quaternion parts)")
    found = data.shape[1] - 1
    if expected_columns is not None and found != expected_columns:
        raise MotionFormatError(
            f"{path}: the model expects {expected_columns} values per frame "
            f"({expected_columns + 1} columns with dt) but the file has {found} "
            f"({found + 1} columns with dt)", found=found
        )
    loop = payload.get("Loop", "wrap")
    motion = Motion(data[:, 1:], data[:, 0], loop=loop, quaternions=quaternions, source=str(path))
    warn_implausible_frame_duration(motion)
    return motion


_warned_frame_duration: set[tuple[str, float, float]] = set()


def warn_implausible_frame_duration(motion: Motion) -> None:
    """One WARNING line (once per file and durations) when a frame duration lies outside
    :data:`PLAUSIBLE_FRAME_DURATION`; a non-positive or non-finite one :class:`Motion` refuses."""
    used = motion.dt[:-1] if motion.num_frames > 1 else motion.dt  # the last frame's duration is never played
    shortest, longest = float(used.min()), float(used.max())
    low, high = PLAUSIBLE_FRAME_DURATION
    key = (str(motion.source), shortest, longest)
    plausible = low <= shortest and longest <= high
    if plausible or key in _warned_frame_duration or not log.isEnabledFor(logging.WARNING):
        return  # in range, said already, or silenced (a job's edge check: the job itself says it, in its log)
    _warned_frame_duration.add(key)
    given = f"{shortest:.4g} s" if shortest == longest else f"{shortest:.4g}-{longest:.4g} s"
    log.warning("%s: frame duration %s is outside the expected range %.4g-%.4g s (1/240 s to 0.1 s; the "
                "thesis' motions use 0.03-0.033 s): the first value of each frame is its duration in seconds; "
                "as given the motion lasts %.4g s", motion.source, given, low, high, motion.duration)


def random_motion(lower: Sequence[float], upper: Sequence[float], seconds: float = 4.0, dt: float = 0.03,
                  keyframe_seconds: float = 0.3, margin: float = 0.05, seed: int = 0,
                  root: Sequence[float] = (0.0, 0.9, 0.0, 1.0, 0.0, 0.0, 0.0)) -> Motion:
    """A random, smooth reference motion within joint limits (the PD-tuning signal).

    Joint values move between uniformly drawn keyframes every ``keyframe_seconds`` with a
    cosine ease, sampled every ``dt``; the root stays at ``root``; the motion does not loop.
    """
    rng = np.random.default_rng(seed)
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    span = upper - lower
    keys = int(math.ceil(seconds / keyframe_seconds)) + 1
    keyframes = lower + margin * span + rng.random((keys, len(lower))) * (1 - 2 * margin) * span
    times = np.arange(0.0, seconds + 1e-9, dt)
    position = times / keyframe_seconds
    index = np.minimum(position.astype(int), keys - 2)
    frac = position - index
    ease = (1 - np.cos(np.pi * np.clip(frac, 0, 1))) / 2
    joints = keyframes[index] + ease[:, None] * (keyframes[index + 1] - keyframes[index])
    frames = np.concatenate([np.tile(np.asarray(root, float), (len(times), 1)), joints], axis=1)
    return Motion(frames, dt, loop="none", source=f"random_motion(seed={seed})")


def mean_joint_speed(motion: Motion, columns: slice | np.ndarray = slice(ROOT_COLUMNS, None)) -> float:
    """Mean |dq/dt| (rad/s) over the frames and the joint ``columns`` of one cycle (the wrap excluded)."""
    if motion.num_frames < 2:
        return 0.0
    q = motion.frames[:, columns]
    return float(np.mean(np.abs(np.diff(q, axis=0)) / motion.dt[:-1, None]))


def generated_motions(examples: Sequence[Motion], lower: Sequence[float], upper: Sequence[float], count: int,
                      seed: int = 0, keyframes: tuple[int, int] = (2, 4), margin: float = 0.05,
                      close_loop: bool = False) -> list[Motion]:
    """``count`` smooth random joint trajectories like ``examples`` (a pool's generated training motions).

    Each takes one example's duration, frame step and root, and its mean joint speed: between 2 and
    4 (``keyframes``) poses drawn uniformly inside ``[lower, upper]`` (``margin`` of each range kept
    clear) with a cosine ease, then scaled about their mean pose so the mean joint speed is the
    example's (clipped back inside the limits). They loop as the examples do: ``close_loop`` False
    leaves the jump from the last pose back to the first that the thesis' letters have at the wrap.
    Only revolute joints (a body whose motion columns after the root are one value per joint).
    """
    if count < 0 or not examples:
        raise ValueError(f"generated motions: count must be >= 0 and examples non-empty, got {count}, "
                         f"{len(examples)} examples")
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    span = upper - lower
    rng = np.random.default_rng(seed)
    motions = []
    for k in range(count):
        example = examples[int(rng.integers(len(examples)))]
        if example.num_columns != ROOT_COLUMNS + len(lower):
            raise ValueError(f"generated motions: {example.source} has {example.num_columns} values per frame, "
                             f"expected {ROOT_COLUMNS} root values and one per joint ({len(lower)})")
        dt = float(np.median(example.dt[:-1])) if example.num_frames > 1 else float(example.dt[0])
        times = np.arange(example.num_frames) * dt
        poses = int(rng.integers(keyframes[0], keyframes[1] + 1))
        keys = lower + margin * span + rng.random((poses + int(close_loop), len(lower))) * (1 - 2 * margin) * span
        if close_loop:
            keys[-1] = keys[0]
        position = times / max(times[-1], 1e-12) * (len(keys) - 1)
        index = np.minimum(position.astype(int), len(keys) - 2)
        ease = (1 - np.cos(np.pi * np.clip(position - index, 0, 1))) / 2
        joints = keys[index] + ease[:, None] * (keys[index + 1] - keys[index])
        speed = float(np.mean(np.abs(np.diff(joints, axis=0)) / dt)) if len(joints) > 1 else 0.0
        if speed > 0:
            centre = joints.mean(axis=0)
            joints = np.clip(centre + (joints - centre) * mean_joint_speed(example) / speed, lower, upper)
        root = np.tile(example.frames[0, :ROOT_COLUMNS], (len(times), 1))
        motions.append(Motion(np.concatenate([root, joints], axis=1), dt, loop=example.loop,
                              source=f"generated(seed={seed}, k={k}, like={Path(str(example.source)).stem})"))
    return motions
