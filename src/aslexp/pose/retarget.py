"""Landmarks -> joint angles of the thesis' hand and upper-body models -> DeepMimic motion files.

Everything is geometry on the models' own URDFs, so that the same code runs both ways:
forward kinematics (:class:`Kinematics`) turns a motion into MediaPipe-like keypoints, and the
retargeters turn keypoints into a motion. Model -> keypoints -> model reproduces the finger,
elbow, wrist, shoulder and neck angles exactly (up to joint limits and, for the chest, the
offset between the hips and the chest joint); tests measure it.

Frames
- MediaPipe world landmarks: metres, x to the image right, y down, z away from the camera.
- The humanoid (DeepMimic): y up, x forward (towards the camera for a signer facing it),
  z to the signer's right. ``MP_TO_HUMANOID`` maps one to the other (a proper rotation).

Hand (15 flexion angles, URDF order thumb, index, middle, ring, pinkie x prox, inter, dist)
- A palm frame from the wrist, index, middle and pinky knuckles (columns: across the knuckles,
  palm normal, wrist -> middle knuckle).
- Each finger's joint axis and rest direction, taken from the model's URDF and expressed in the
  model's own palm frame, are carried into the observed palm frame. The three bones are projected
  on the plane normal to that axis: the proximal angle is the signed angle from the rest direction
  to the first bone, the next two the signed angles between consecutive bones (flexion > 0).
  The thumb of this model flexes across the palm (about the palm normal); the same rule covers it.
- A left hand is the mirror image of a right one; the model's left hand mirrors its right
  (finger axes -x), so both are handled by the same rule with each model's own constants.

Upper body (76-column files): chest and neck quaternions from the torso and head frames;
per arm the elbow angle from the upper-arm and forearm directions, the shoulder quaternion that
puts the upper arm along the observed one and the elbow's bending plane through the forearm (for
a nearly straight arm the plane comes from the palm), the wrist angle from the forearm to the
hand direction about the elbow's flexion axis; both hands' fingers as above. The model has no
forearm twist, so the palm's roll about the forearm is not reproduced. Where a hand's own landmarks
are missing (a MediaPipe Pose array has none), ``pose_hand_points`` takes the hand's direction and
palm from Pose's wrist, index and pinky knuckles instead (:func:`pose_hands`): the wrist turns, the
fingers stay at rest.

Gaps (frames without a hand or a body) are filled by linear interpolation over time, then the
angles are smoothed with a Gaussian (``sigma`` frames) and clipped to the URDF limits.

Plausibility: a motion whose keypoints hold a joint far past its limit most of the time, or whose
arms are deeper than a body reaches, gets ``warnings`` in its report naming the joints or the
proportions and the frames (:func:`limit_warnings`, :func:`depth_warning`; the thresholds and
their measurements are beside them); ``aslexp extract --motions`` prints them.
"""

from __future__ import annotations

import json
import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np

from aslexp.files import atomic_write_text
from aslexp.keypoints import holistic as H
from aslexp.quaternion import from_matrix as matrix_to_quat
from aslexp.quaternion import to_matrix as quat_to_matrix

MP_TO_HUMANOID = np.array([[0.0, 0.0, -1.0], [0.0, -1.0, 0.0], [-1.0, 0.0, 0.0]])

FINGERS = ("thumb", "index", "middle", "ring", "pinkie")
PHALANGES = ("prox", "inter", "dist")
HAND_JOINTS = tuple(f"{f}_{p}" for f in FINGERS for p in PHALANGES)
# MediaPipe hand landmark chains (base, then the three bone ends) per model finger.
FINGER_CHAINS = {"thumb": (1, 2, 3, 4), "index": (5, 6, 7, 8), "middle": (9, 10, 11, 12),
                 "ring": (13, 14, 15, 16), "pinkie": (17, 18, 19, 20)}  # fmt: skip
FINGERTIP_OFFSET = np.array([0.0, 0.0, 0.04])  # distal links are 0.04 boxes along +z
HAND_ROOT = (0.0, 0.9, 0.0, 1.0, 0.0, 0.0, 0.0)  # as in the thesis' hand files
UPPER_ROOT = (0.0, 0.9, 0.0, 1.0, 0.0, 0.0, 0.0)

# The 76-column upper-body files after dt: root (7) then these joints (width 4 = quaternion).
UPPER_BODY_COLUMNS: tuple[tuple[str, int], ...] = (
    ("chest", 4), ("neck", 4),
    ("right_hip", 4), ("right_knee", 1), ("right_ankle", 4),
    ("right_shoulder", 4), ("right_elbow", 1), ("right_wrist", 1),
    *((f"r_{j}", 1) for j in HAND_JOINTS),
    ("left_hip", 4), ("left_knee", 1), ("left_ankle", 4),
    ("left_shoulder", 4), ("left_elbow", 1), ("left_wrist", 1),
    *((f"l_{j}", 1) for j in HAND_JOINTS),
)  # fmt: skip
HAND_FILE_VALUES = 7 + 15  # 23 columns with dt
UPPER_FILE_VALUES = 7 + sum(w for _, w in UPPER_BODY_COLUMNS)  # 75 values, 76 columns with dt

# Head points in the humanoid's neck link frame (the URDF head is a sphere at y = 0.7): the
# ears on either side and the nose in front, a little below the ears as on a person looking
# straight ahead (MediaPipe's ear landmarks sit at the tragus, above the nose tip).
HEAD_POINTS = {"left_ear": (0.0, 0.7, -0.3), "right_ear": (0.0, 0.7, 0.3), "nose": (0.4, 0.62, 0.0)}

DATA_MODELS = Path("models")


# ----------------------------------------------------------------------------- rotations


def _normalize(v: np.ndarray, axis: int = -1) -> np.ndarray:
    n = np.linalg.norm(v, axis=axis, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        return v / n


def rpy_matrix(rpy) -> np.ndarray:
    """URDF fixed-axis roll, pitch, yaw: R = Rz(yaw) Ry(pitch) Rx(roll)."""
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array([
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ])  # fmt: skip


def axis_angle_matrix(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """(F, 3, 3) rotations about a fixed unit ``axis`` by ``angle`` (F,) (Rodrigues)."""
    axis = np.asarray(axis, dtype=float)
    axis = axis / np.linalg.norm(axis)
    angle = np.asarray(angle, dtype=float)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    s, c = np.sin(angle)[:, None, None], np.cos(angle)[:, None, None]
    return np.eye(3) + s * k + (1 - c) * (k @ k)


def signed_angle(u: np.ndarray, v: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """Angle from u to v about ``axis`` (right-hand rule), all (..., 3)."""
    return np.arctan2(np.sum(np.cross(u, v) * axis, -1), np.sum(u * v, -1))


def _project(v: np.ndarray, axis: np.ndarray) -> np.ndarray:
    return v - np.sum(v * axis, -1, keepdims=True) * axis


# ----------------------------------------------------------------------------- kinematics


@dataclass(frozen=True)
class Joint:
    name: str
    type: str
    parent: str
    child: str
    xyz: tuple[float, float, float]
    rpy: tuple[float, float, float]
    axis: tuple[float, float, float]
    lower: float | None
    upper: float | None


class Kinematics:
    """Forward kinematics of a URDF tree (link frames, unscaled URDF units), batched over frames."""

    def __init__(self, joints: list[Joint], source: str = "urdf"):
        self.joints = {j.name: j for j in joints}
        self.by_child = {j.child: j for j in joints}
        self.children: dict[str, list[Joint]] = {}
        for j in joints:
            self.children.setdefault(j.parent, []).append(j)
        self.source = source

    @classmethod
    def from_urdf(cls, path: str | os.PathLike) -> "Kinematics":
        root = ET.parse(path).getroot()
        joints = []
        for el in root.findall("joint"):
            origin = el.find("origin")
            axis = el.find("axis")
            limit = el.find("limit")

            def floats(node, key, default):
                return tuple(float(v) for v in node.get(key).split()) if node is not None and node.get(key) else default

            joints.append(Joint(
                name=el.get("name"), type=el.get("type"),
                parent=el.find("parent").get("link"), child=el.find("child").get("link"),
                xyz=floats(origin, "xyz", (0.0, 0.0, 0.0)), rpy=floats(origin, "rpy", (0.0, 0.0, 0.0)),
                axis=floats(axis, "xyz", (1.0, 0.0, 0.0)),
                lower=float(limit.get("lower")) if limit is not None and limit.get("lower") else None,
                upper=float(limit.get("upper")) if limit is not None and limit.get("upper") else None,
            ))  # fmt: skip
        return cls(joints, source=str(path))

    def forward(
        self, values: dict[str, np.ndarray], root_link: str, frames: int
    ) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """World (root-link) rotation (F, 3, 3) and position (F, 3) of every link below
        ``root_link``. ``values``: revolute joint -> (F,) angles, spherical -> (F, 4) (w, x, y, z);
        absent joints stay at zero."""
        eye = np.broadcast_to(np.eye(3), (frames, 3, 3)).copy()
        poses = {root_link: (eye, np.zeros((frames, 3)))}
        stack = [root_link]
        while stack:
            link = stack.pop()
            rot, pos = poses[link]
            for j in self.children.get(link, []):
                child_pos = pos + rot @ np.asarray(j.xyz)
                child_rot = rot @ rpy_matrix(j.rpy)
                if j.type in ("revolute", "continuous", "prismatic") and j.name in values:
                    child_rot = child_rot @ axis_angle_matrix(j.axis, np.asarray(values[j.name], float))
                elif j.type == "spherical" and j.name in values:
                    child_rot = child_rot @ quat_to_matrix(np.asarray(values[j.name], float))
                poses[j.child] = (child_rot, child_pos)
                stack.append(j.child)
        return poses

    def limits(self, names) -> tuple[np.ndarray, np.ndarray]:
        lower = np.array([self.joints[n].lower for n in names], dtype=float)
        upper = np.array([self.joints[n].upper for n in names], dtype=float)
        return lower, upper


def models_dir(data_root: str | os.PathLike | None = None) -> Path:
    from aslexp.data.root import resolve_data_root

    return resolve_data_root(data_root) / DATA_MODELS


@lru_cache(maxsize=8)
def _kinematics(path: str) -> Kinematics:
    return Kinematics.from_urdf(path)


def hand_kinematics(data_root=None) -> Kinematics:
    return _kinematics(str(models_dir(data_root) / "final_hand.urdf"))


def upper_body_kinematics(data_root=None) -> Kinematics:
    return _kinematics(str(models_dir(data_root) / "whole_upper_humanoid.urdf"))


# ----------------------------------------------------------------------------- hands


def palm_frame(kp: np.ndarray) -> np.ndarray:
    """(..., 3, 3) palm frames from (..., 21, 3) hand landmarks. Columns: across the knuckles
    (pinky -> index side), the normal cross(across, forward), forward (wrist -> middle knuckle)."""
    forward = _normalize(kp[..., 9, :] - kp[..., 0, :])
    across = kp[..., 5, :] - kp[..., 17, :]
    normal = _normalize(np.cross(across, forward))
    across = np.cross(forward, normal)
    return np.stack([across, normal, forward], axis=-1)


@dataclass
class HandModel:
    """A model hand as the retargeter needs it: joints in motion order, limits, and per finger
    the joint axis and the rest direction of the first bone in the model's palm frame."""

    kinematics: Kinematics
    wrist_link: str
    joint_names: tuple[str, ...]
    lower: np.ndarray
    upper: np.ndarray
    axes_palm: np.ndarray = field(repr=False)  # (5, 3)
    rest_palm: np.ndarray = field(repr=False)  # (5, 3)

    @classmethod
    def from_kinematics(cls, kin: Kinematics, prefix: str, wrist_link: str) -> "HandModel":
        names = tuple(prefix + j for j in HAND_JOINTS)
        lower, upper = kin.limits(names)
        model = cls(kin, wrist_link, names, lower, upper, np.zeros((5, 3)), np.zeros((5, 3)))
        poses = kin.forward({}, wrist_link, 1)
        kp = model.keypoints(np.zeros((1, 15)))[0]
        palm = palm_frame(kp)
        for k, finger in enumerate(FINGERS):
            joint = kin.joints[prefix + f"{finger}_prox"]
            rot = poses[joint.child][0][0]  # the joint frame at rest
            axis = rot @ np.asarray(joint.axis) / np.linalg.norm(joint.axis)
            base, nxt = FINGER_CHAINS[finger][:2]
            rest = _normalize(kp[nxt] - kp[base])
            model.axes_palm[k] = palm.T @ axis
            model.rest_palm[k] = palm.T @ rest
        return model

    def keypoints(self, angles: np.ndarray, poses=None) -> np.ndarray:
        """(F, 21, 3) MediaPipe-ordered hand keypoints of the model in its wrist frame (or, with
        ``poses`` from a larger body's forward kinematics, in that body's frame)."""
        angles = np.atleast_2d(angles)
        if poses is None:
            poses = self.kinematics.forward(dict(zip(self.joint_names, angles.T)), self.wrist_link, len(angles))
        prefix = self.joint_names[0][: -len(HAND_JOINTS[0])]
        out = np.empty((len(angles), 21, 3))
        out[:, 0] = poses[self.wrist_link][1]
        for finger, chain in FINGER_CHAINS.items():
            links = [self.kinematics.joints[f"{prefix}{finger}_{p}"].child for p in PHALANGES]
            for k, link in enumerate(links):
                out[:, chain[k]] = poses[link][1]
            rot, pos = poses[links[-1]]
            out[:, chain[3]] = pos + rot @ FINGERTIP_OFFSET
        return out


@lru_cache(maxsize=8)
def _hand_model(path: str, prefix: str, wrist_link: str) -> HandModel:
    return HandModel.from_kinematics(_kinematics(path), prefix, wrist_link)


def final_hand_model(data_root=None) -> HandModel:
    """The thesis' standalone 15-DoF right hand (final_hand.urdf)."""
    return _hand_model(str(models_dir(data_root) / "final_hand.urdf"), "", "right_wrist")


def upper_hand_model(side: str, data_root=None) -> HandModel:
    """The right ('r_') or left ('l_') hand of the upper-body humanoid."""
    prefix, wrist = {"right": ("r_", "right_wrist"), "left": ("l_", "left_wrist")}[side]
    return _hand_model(str(models_dir(data_root) / "whole_upper_humanoid.urdf"), prefix, wrist)


def hand_angles(kp: np.ndarray, model: HandModel) -> np.ndarray:
    """(T, 21, 3) hand landmarks -> (T, 15) raw flexion angles (not clipped; NaN where missing)."""
    kp = np.asarray(kp, dtype=float)
    palm = palm_frame(kp)  # (T, 3, 3)
    out = np.empty(kp.shape[:-2] + (15,))
    for k, finger in enumerate(FINGERS):
        axis = palm @ model.axes_palm[k]
        rest = palm @ model.rest_palm[k]
        c = FINGER_CHAINS[finger]
        bones = [kp[..., c[i + 1], :] - kp[..., c[i], :] for i in range(3)]
        vecs = [_project(v, axis) for v in [rest, *bones]]
        for i in range(3):
            out[..., 3 * k + i] = signed_angle(vecs[i], vecs[i + 1], axis)
    return out


def mirror_hand(kp: np.ndarray) -> np.ndarray:
    """A left hand's landmarks as a right hand's (and back): reflect across a plane."""
    return np.asarray(kp) * np.array([-1.0, 1.0, 1.0])


# ----------------------------------------------------------------------------- time series


def fill_gaps(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Linear interpolation over NaN rows (edges hold the nearest value). Returns the filled
    array and the (T,) mask of rows that were observed; all-NaN columns stay NaN."""
    values = np.array(values, dtype=float)
    observed = np.all(np.isfinite(values.reshape(len(values), -1)), axis=1)
    if observed.all() or not observed.any():
        return values, observed
    t = np.arange(len(values))
    flat = values.reshape(len(values), -1)
    for col in range(flat.shape[1]):
        flat[:, col] = np.interp(t, t[observed], flat[observed, col])
    return flat.reshape(values.shape), observed


def smooth(values: np.ndarray, sigma: float) -> np.ndarray:
    """Zero-phase Gaussian smoothing along time (axis 0), edges held."""
    if sigma <= 0 or len(values) < 2:
        return values
    from scipy.ndimage import gaussian_filter1d

    return gaussian_filter1d(values, sigma=sigma, axis=0, mode="nearest")


def smooth_quaternions(q: np.ndarray, sigma: float) -> np.ndarray:
    """(T, 4) quaternions: sign continuity, component smoothing, renormalisation."""
    q = np.array(q, dtype=float)
    for t in range(1, len(q)):
        if np.dot(q[t], q[t - 1]) < 0:
            q[t] = -q[t]
    q = _normalize(smooth(q, sigma))
    return q * np.where(q[:, :1] < 0, -1.0, 1.0)


# ----------------------------------------------------------------------------- hand motion


@dataclass
class RetargetResult:
    """A motion's values plus what the retargeter had to do to get them."""

    frames: np.ndarray  # (T, D) values without dt (root first)
    dt: float
    report: dict

    def motion(self):
        from aslexp.sim.motion import Motion

        quats = [3] + [7 + off for off in _quaternion_offsets()] if self.frames.shape[1] == UPPER_FILE_VALUES else [3]
        return Motion(self.frames, self.dt, loop="wrap", quaternions=quats)

    def save(self, path: str | os.PathLike) -> Path:
        from aslexp.sim.motion import save_motion

        return save_motion(self.motion(), path)


def _quaternion_offsets() -> list[int]:
    offsets, col = [], 0
    for _, width in UPPER_BODY_COLUMNS:
        if width == 4:
            offsets.append(col)
        col += width
    return offsets


# ----------------------------------------------------------------------------- plausibility

# What the terminal warns about, measured on the six WLASL clips' MediaPipe world
# landmarks (normal), the same clips as .pose files without a world component (lifted from the
# image, as pose-format's video_to_pose writes them) and with their depth scaled by 5:
# - A joint held at its URDF limit while the keypoints ask for more than LIMIT_MARGIN beyond it, in
#   more than LIMIT_SHARE_WARN of the frames it was seen in. A small excess is routine: the fingers'
#   [0, 2] rad is passed by more than 0.05 rad in up to 87% of frames on the normal clips (the
#   thumb's first joint, which MediaPipe reads hyperextended); by more than 0.35 rad (20 degrees)
#   in at most a third (the whistle's right ring and little fingers 0.33, its right wrist 0.32: the
#   hand at the mouth), the most of any joint. Half the frames leaves a margin above that; the
#   issue's foreign .pose held the right wrist past its limit in 92%.
# - Arms deeper than DEPTH_RATIO_WARN shoulder widths (the front-to-back extent of the shoulders,
#   elbows and wrists) in more than LIMIT_SHARE_WARN of the frames. A person's arm is about 1.6
#   shoulder widths long; the normal clips reach at most 1.37 in any frame, the thesis' four signs
#   1.04; lifted from the image 1.5-4.1 (median per clip: MediaPipe's image depth is on another
#   scale), 5.7-16.7 with the depth scaled by 5.
LIMIT_TOLERANCE = 0.05  # rad: past a limit by this much counts in the reports' fractions
LIMIT_MARGIN = 0.35  # rad: past a limit by this much is more than landmark noise
LIMIT_SHARE_WARN = 0.5
LIMIT_MIN_FRAMES = 5  # fewer frames past a limit are a glimpse (a hand found in a few frames), not a hold
DEPTH_RATIO_WARN = 2.0
ARM_POINTS = ("left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist")


def _clip_report(raw: np.ndarray, lower: np.ndarray, upper: np.ndarray, tol: float = LIMIT_TOLERANCE) -> float:
    finite = np.isfinite(raw)
    outside = finite & ((raw < lower - tol) | (raw > upper + tol))
    return float(outside.sum() / max(finite.sum(), 1))


def frame_ranges(frames: np.ndarray, shown: int = 4) -> str:
    """Frame indices as ranges, '3-40, 45, 50-56' (the first ``shown`` ranges, then a count)."""
    frames = np.asarray(frames, dtype=int)
    if not len(frames):
        return "none"
    breaks = np.flatnonzero(np.diff(frames) > 1)
    starts = np.concatenate([[frames[0]], frames[breaks + 1]])
    ends = np.concatenate([frames[breaks], [frames[-1]]])
    spans = [f"{a}" if a == b else f"{a}-{b}" for a, b in zip(starts, ends)]
    more = f", ... ({len(spans)} ranges)" if len(spans) > shown else ""
    return ", ".join(spans[:shown]) + more


def limit_warnings(raw: np.ndarray, lower: np.ndarray, upper: np.ndarray, names,
                   margin: float = LIMIT_MARGIN, share: float = LIMIT_SHARE_WARN) -> tuple[dict, list[str]]:  # fmt: skip
    """Per joint (columns of a (T, J) raw angle array, NaN where unseen): the share of its seen
    frames whose raw angle lies more than ``margin`` past a limit (joints with any), and one
    warning per joint where that share exceeds ``share``, naming the joint, its limits and the
    frames (0-based, as in the motion); a joint past its limit in fewer than :data:`LIMIT_MIN_FRAMES`
    frames is not warned about."""
    raw = np.asarray(raw, dtype=float).reshape(len(raw), -1)
    seen = np.isfinite(raw)
    with np.errstate(invalid="ignore"):
        beyond = seen & ((raw < np.asarray(lower) - margin) | (raw > np.asarray(upper) + margin))
    shares, warnings = {}, []
    for j, name in enumerate(names):
        if not beyond[:, j].any():
            continue
        fraction = float(beyond[:, j].sum() / seen[:, j].sum())
        shares[name] = round(fraction, 3)
        if fraction > share and beyond[:, j].sum() >= LIMIT_MIN_FRAMES:
            low, high = float(np.ravel(lower)[j]), float(np.ravel(upper)[j])
            warnings.append(f"{name} held at its limit ([{low:.2f}, {high:.2f}] rad; the keypoints ask for more "
                            f"than {margin} rad beyond) in {fraction:.0%} of its {int(seen[:, j].sum())} frames "
                            f"(frames {frame_ranges(np.flatnonzero(beyond[:, j]))})")  # fmt: skip
    return shares, warnings


def depth_warning(body: dict[str, np.ndarray], ratio: float = DEPTH_RATIO_WARN,
                  share: float = LIMIT_SHARE_WARN) -> tuple[float | None, list[str]]:  # fmt: skip
    """The arms' depth over the shoulder width (front-to-back extent, humanoid x, of the shoulders,
    elbows and wrists, over the shoulders' distance), median over the frames with both arms; and a
    warning naming the frames above ``ratio`` when they are more than ``share`` of them."""
    points = np.stack([np.asarray(body[n], dtype=float) for n in ARM_POINTS], axis=1)  # (T, 6, 3)
    width = np.linalg.norm(points[:, 1] - points[:, 0], axis=-1)
    ok = np.isfinite(points).all(axis=(1, 2)) & (width > 1e-9)
    if not ok.any():
        return None, []
    depth = np.full(len(points), np.nan)
    depth[ok] = np.ptp(points[ok, :, 0], axis=1) / width[ok]
    median = float(np.median(depth[ok]))
    with np.errstate(invalid="ignore"):
        deep = np.flatnonzero(depth > ratio)
    if len(deep) <= share * ok.sum():
        return round(median, 3), []
    return round(median, 3), [f"implausible proportions: the arms are {median:.1f} shoulder widths deep (median; "
                              f"a person's arm is about 1.6 long) and more than {ratio:g} in {len(deep)} of "
                              f"{int(ok.sum())} frames (frames {frame_ranges(deep)}): the depth axis is likely on "
                              "another scale than x and y (e.g. MediaPipe's image z, lifted as it is where a file "
                              "has no world component)"]  # fmt: skip


# A motion is implausible (marked in its report; a training pool leaves it out and counts it) when
# any of these holds; each is also a WARNING line. Jumps: an elbow or wrist moving faster than
# JUMP_SPEED_WARN shoulder widths a second between two frames (about 11 m/s: no signer's hand moves
# so, sign peak wrist speeds are 2-3 m/s = 6-8 widths/s; the thesis' own four signs reach 5.1-8.2,
# and 26.8 in one frame of 69318; on the 291 WLASL Pose arrays the median clip's fastest frame is 8.3,
# the 95th percentile 23). Out of view: the better seen arm seen (not guessed) in under SEEN_SHARE_MIN of
# the frames (a one-handed sign's resting arm is often below the frame: that alone is no reason).
JUMP_SPEED_WARN = 30.0  # shoulder widths per second
SEEN_SHARE_MIN = 0.5
JUMP_POINTS = ("left_elbow", "right_elbow", "left_wrist", "right_wrist")


def jump_warning(body: dict[str, np.ndarray], fps: float,
                 speed: float = JUMP_SPEED_WARN) -> tuple[float | None, list[str]]:  # fmt: skip
    """The fastest elbow or wrist speed between consecutive frames, in shoulder widths per second,
    and a warning naming the point and frames where it exceeds ``speed`` (a tracking jump)."""
    width = np.nanmedian(np.linalg.norm(np.asarray(body["right_shoulder"]) - np.asarray(body["left_shoulder"]), axis=-1))
    if not np.isfinite(width) or width <= 1e-9 or len(body["left_wrist"]) < 2:
        return None, []
    speeds = {n: np.linalg.norm(np.diff(np.asarray(body[n], dtype=float), axis=0), axis=-1) * fps / width
              for n in JUMP_POINTS}  # fmt: skip
    finite = [v[np.isfinite(v)] for v in speeds.values()]
    fastest = max((float(v.max()) for v in finite if len(v)), default=None)
    jumps = {n: np.flatnonzero(v > speed) for n, v in speeds.items() if np.any(v > speed)}
    if not jumps:
        return (round(fastest, 2) if fastest is not None else None), []
    named = "; ".join(f"{n} at frames {frame_ranges(frames + 1)}" for n, frames in jumps.items())
    return round(fastest, 2), [f"jumps: {named} move faster than {speed:g} shoulder widths a second (fastest "
                               f"{fastest:.0f}; a hand moves at most about 8): a tracking error"]


def motion_plausibility(report: dict, body: dict[str, np.ndarray], fps: float, seen_share: float | None = None) -> dict:
    """Whether an upper-body motion is plausible, and if not why, by kind: ``joint_limits`` (a joint
    held past its limit: the report's ``past_limits``, arms and fingers, over LIMIT_SHARE_WARN),
    ``depth`` (:func:`depth_warning`), ``jumps`` (:func:`jump_warning`), ``out_of_view`` (``seen_share``,
    the share of frames where the better seen arm is seen, under SEEN_SHARE_MIN); the measures
    behind each in ``checks``."""
    limits = dict(report.get("past_limits", {}))
    for side in ("right", "left"):
        limits.update(report.get(f"{side}_hand", {}).get("past_limits", {}))
    held = sorted(name for name, share in limits.items() if share > LIMIT_SHARE_WARN)
    depth, depth_lines = depth_warning(body)
    fastest, jump_lines = jump_warning(body, fps)
    reasons: dict[str, str] = {}
    if held:
        reasons["joint_limits"] = (f"held past their limits in over {LIMIT_SHARE_WARN:.0%} of the frames: "
                                   f"{', '.join(held)}")  # fmt: skip
    if depth_lines:
        reasons["depth"] = f"the arms are {depth} shoulder widths deep (median; above {DEPTH_RATIO_WARN:g})"
    if jump_lines:
        reasons["jumps"] = jump_lines[0].removeprefix("jumps: ")
    if seen_share is not None and seen_share < SEEN_SHARE_MIN:
        reasons["out_of_view"] = (f"the better seen arm is seen in {seen_share:.0%} of the frames (under "
                                  f"{SEEN_SHARE_MIN:.0%})")  # fmt: skip
    checks = {"depth_to_width": depth, "fastest_shoulder_widths_per_s": fastest, "arm_seen_share": seen_share,
              "joints_past_limits": limits}  # fmt: skip
    return {"plausible": not reasons, "reasons": reasons, "checks": checks, "warnings": jump_lines}


def finger_angles(
    kp: np.ndarray, model: HandModel, sigma: float = 1.0, min_coverage: float = 0.0
) -> tuple[np.ndarray, dict]:
    """(T, 21, 3) landmarks (NaN where missing) -> (T, 15) filled, smoothed, clipped angles; the
    report counts the frames and, per joint, the share of frames far past its limits
    (``past_limits``; ``warnings`` for those held there most of the time: :func:`limit_warnings`)."""
    raw = hand_angles(kp, model)
    filled, observed = fill_gaps(raw)
    coverage = float(observed.mean()) if len(observed) else 0.0
    if not observed.any() or coverage < min_coverage:
        raise ValueError(f"hand seen in {observed.sum()} of {len(observed)} frames")
    angles = np.clip(smooth(filled, sigma), model.lower, model.upper)
    shares, warnings = limit_warnings(raw, model.lower, model.upper, model.joint_names)
    report = {"frames_observed": int(observed.sum()), "coverage": round(coverage, 3),
              "fraction_outside_limits": round(_clip_report(raw, model.lower, model.upper), 3),
              "past_limits": shares, "warnings": warnings}  # fmt: skip
    return angles, report


def hand_motion_from_landmarks(
    kp: np.ndarray, fps: float, side: str = "right", sigma: float = 1.0, data_root=None
) -> RetargetResult:
    """Hand landmarks (T, 21, 3) of the signer's ``side`` hand -> 23-column hand motion for the
    right-hand model (a left hand is mirrored first)."""
    model = final_hand_model(data_root)
    points = mirror_hand(kp) if side == "left" else np.asarray(kp, dtype=float)
    angles, report = finger_angles(points, model, sigma)
    frames = np.concatenate([np.tile(HAND_ROOT, (len(angles), 1)), angles], axis=1)
    report.update(side=side, mirrored=side == "left")
    return RetargetResult(frames, 1.0 / fps, report)


def hand_angles_to_keypoints(angles: np.ndarray, data_root=None) -> np.ndarray:
    """Forward kinematics of the standalone hand: (F, 15) -> (F, 21, 3) in its wrist frame."""
    return final_hand_model(data_root).keypoints(np.asarray(angles, float))


# ----------------------------------------------------------------------------- upper body


def _frame_from(right: np.ndarray, up: np.ndarray) -> np.ndarray:
    """Rotation with columns (forward, up, right) from a right-pointing and an up-ish vector."""
    z = _normalize(right)
    x = _normalize(np.cross(up, z))
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=-1)


@dataclass
class UpperBodyModel:
    kinematics: Kinematics
    torso_rest: np.ndarray  # 3x3 frame of the rest torso keypoints
    head_rest: np.ndarray  # 3x3 frame of the rest head keypoints (in the neck link frame)
    hands: dict[str, HandModel]
    wrist_offset: float = 0.0
    torso_a: np.ndarray = field(default_factory=lambda: np.zeros(3), repr=False)
    torso_b: np.ndarray = field(default_factory=lambda: np.array([0.0, 1.0, 0.0]), repr=False)

    def chest_rotation(self, right: np.ndarray, up: np.ndarray, iterations: int = 3) -> np.ndarray:
        """(T, 3, 3) chest rotations from the shoulder line and hips -> shoulders vectors.

        hips -> shoulders = a + R b (a: hips -> chest joint, fixed; b: chest joint -> shoulders,
        turned by the chest R), both scaled to the observed torso: solved by a few fixed-point
        steps (exact on the model itself)."""
        rot = np.broadcast_to(np.eye(3), right.shape[:-1] + (3, 3)).copy()
        for _ in range(iterations):
            length = np.linalg.norm(self.torso_a + rot @ self.torso_b, axis=-1, keepdims=True)
            scale = np.linalg.norm(up, axis=-1, keepdims=True) / length
            turned = up / scale - self.torso_a  # = R b
            rot = _frame_from(right, turned) @ self.torso_rest.T
        return rot

    @classmethod
    def load(cls, data_root=None) -> "UpperBodyModel":
        kin = upper_body_kinematics(data_root)
        poses = kin.forward({}, "base", 1)
        pts = {name: p[0] for name, p in _body_points(kin, poses).items()}
        hip_mid = (pts["right_hip"] + pts["left_hip"]) / 2
        chest_origin = poses["chest"][1][0]
        torso_a = chest_origin - hip_mid  # does not turn with the chest
        torso_b = (pts["right_shoulder"] + pts["left_shoulder"]) / 2 - chest_origin  # turns with it
        torso = _frame_from(pts["right_shoulder"] - pts["left_shoulder"], torso_b)
        head = _head_frame(pts)
        # The arm solver below assumes the thesis humanoid's arm geometry; check it.
        for side in ("right", "left"):
            elbow, wrist = kin.joints[f"{side}_elbow"], kin.joints[f"{side}_wrist"]
            assert np.allclose(_normalize(np.array(elbow.xyz)), [0, -1, 0]) and np.allclose(elbow.axis, [0, 0, 1])
            assert np.allclose(_normalize(np.array(wrist.xyz)), [0, -1, 0]) and np.allclose(wrist.axis, [1, 0, 0])
            assert np.allclose(wrist.rpy, [np.pi / 2, 0, 0], atol=1e-2) and np.allclose(wrist.rpy[1:], 0)
        # The wrist frame is the elbow frame turned by rpy[0] (1.57, not quite pi/2) about x:
        # at wrist angle 0 the hand points that far from the forearm.
        wrist_offset = np.pi / 2 - kin.joints["right_wrist"].rpy[0]
        hands = {s: upper_hand_model(s, data_root) for s in ("right", "left")}
        return cls(kin, torso, head, hands, wrist_offset, torso_a, torso_b)


def _body_points(kin: Kinematics, poses) -> dict[str, np.ndarray]:
    """MediaPipe-like body points of the humanoid: joint origins, and head points on the neck."""
    pts = {}
    for side in ("left", "right"):
        for part in ("shoulder", "elbow", "wrist", "hip"):
            pts[f"{side}_{part}"] = poses[kin.joints[f"{side}_{part}"].child][1]
    rot, pos = poses["neck"]
    for name, offset in HEAD_POINTS.items():
        pts[name] = pos + rot @ np.asarray(offset)
    return pts


def _head_frame(pts: dict[str, np.ndarray]) -> np.ndarray:
    ear_mid = (pts["left_ear"] + pts["right_ear"]) / 2
    right = pts["right_ear"] - pts["left_ear"]
    forward = pts["nose"] - ear_mid
    x = _normalize(forward - np.sum(forward * _normalize(right), -1, keepdims=True) * _normalize(right))
    z = _normalize(right)
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=-1)


@lru_cache(maxsize=4)
def _upper_model(root: str) -> UpperBodyModel:
    return UpperBodyModel.load(root)


def upper_body_model(data_root=None) -> UpperBodyModel:
    return _upper_model(str(models_dir(data_root).parent))


def upper_body_joints(frames: np.ndarray) -> dict[str, np.ndarray]:
    """(F, 75) upper-body values (root first, no dt) -> {joint: (F,) or (F, 4)}."""
    frames = np.atleast_2d(frames)
    if frames.shape[1] != UPPER_FILE_VALUES:
        raise ValueError(f"upper-body frames need {UPPER_FILE_VALUES} values, got {frames.shape[1]}")
    out, col = {}, 7
    for name, width in UPPER_BODY_COLUMNS:
        out[name] = frames[:, col] if width == 1 else frames[:, col : col + 4]
        col += width
    return out


def upper_body_frames(joints: dict[str, np.ndarray], frames: int) -> np.ndarray:
    """{joint: values} -> (F, 75); absent joints are identity / zero."""
    out = np.zeros((frames, UPPER_FILE_VALUES))
    out[:, :7] = UPPER_ROOT
    col = 7
    for name, width in UPPER_BODY_COLUMNS:
        if name in joints:
            out[:, col : col + width] = np.reshape(joints[name], (frames, width))
        elif width == 4:
            out[:, col] = 1.0
        col += width
    return out


def upper_body_keypoints(frames: np.ndarray, data_root=None) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Forward kinematics of a 76-column motion's frames (F, 75): body points {name: (F, 3)}
    and hand landmarks {side: (F, 21, 3)}, in the humanoid frame (y up, x forward, z right)."""
    model = upper_body_model(data_root)
    joints = upper_body_joints(frames)
    values = {k: v for k, v in joints.items() if model.kinematics.joints[k].type != "fixed"}
    poses = model.kinematics.forward(values, "base", len(frames))
    body = _body_points(model.kinematics, poses)
    hands = {side: model.hands[side].keypoints(np.zeros((len(frames), 15)), poses) for side in ("right", "left")}
    return body, hands


def humanoid_inputs_from_world(world: np.ndarray) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """(T, 75, 3) holistic world landmarks (MediaPipe axes) -> body points and hands in the
    humanoid frame, the inputs of :func:`retarget_upper_body`."""
    pts = np.asarray(world, dtype=float) @ MP_TO_HUMANOID.T
    body = {name: pts[:, H.POSE_NAMES.index(name)] for name in
            ("nose", "left_ear", "right_ear", "left_shoulder", "right_shoulder", "left_elbow",
             "right_elbow", "left_wrist", "right_wrist", "left_hip", "right_hip")}  # fmt: skip
    hands = {"left": pts[:, H.LEFT_HAND_OFFSET : H.LEFT_HAND_OFFSET + 21],
             "right": pts[:, H.RIGHT_HAND_OFFSET : H.RIGHT_HAND_OFFSET + 21]}  # fmt: skip
    return body, hands


def pose_hands(world: np.ndarray) -> dict[str, np.ndarray]:
    """(T, 75, 3) holistic world landmarks (MediaPipe axes) -> {side: (T, 21, 3)} coarse hands in the
    humanoid frame from Pose's own hand points, what the arm's solve reads of a hand: the wrist (0),
    the index (5) and pinky (17) knuckles (Pose's "index" and "pinky" are the first knuckles), the
    middle (9) and ring (13) knuckles a third and two thirds of the way between them; the rest NaN.
    A frame without a point is NaN (a Pose array's points below visibility 0.5 are)."""
    pts = np.asarray(world, dtype=float) @ MP_TO_HUMANOID.T
    out = {}
    for side in ("left", "right"):
        wrist, index, pinky = (pts[:, H.POSE_NAMES.index(f"{side}_{name}")] for name in ("wrist", "index", "pinky"))
        hand = np.full((len(pts), 21, 3), np.nan)
        hand[:, 0], hand[:, 5], hand[:, 17] = wrist, index, pinky
        hand[:, 9], hand[:, 13] = index + (pinky - index) / 3, index + 2 * (pinky - index) / 3
        out[side] = hand
    return out


ARM_HAND_POINTS = (0, 5, 9, 17)  # what the arm's solve reads of a hand: palm_frame's points


def _solve_arm(side, s, e, w, hand, chest_rot, prev_bend, wrist_offset=0.0):
    """Shoulder quaternion, elbow and wrist angles for one frame in world coordinates.

    s, e, w: shoulder, elbow, wrist (3,); hand: (21, 3) or None; chest_rot: 3x3 world chest
    rotation; prev_bend: the previous frame's bending direction in the chest frame (or None).
    """
    up = _normalize(chest_rot.T @ (e - s))  # upper arm, chest frame
    fore = _normalize(chest_rot.T @ (w - e))
    bend_angle = float(np.arctan2(np.linalg.norm(np.cross(up, fore)), np.dot(up, fore)))
    bend_arm = _normalize(fore - np.dot(fore, up) * up)
    bend_hand = None
    if hand is not None:
        # Nearly straight arm: the elbow's flexion axis lies across the palm (the model's palm
        # faces the body's midline at rest), which fixes the bending plane.
        h_local = (chest_rot.T @ (hand - hand[0]).T).T
        frame = palm_frame(h_local)
        normal = frame[:, 1] * (1.0 if side == "right" else -1.0)  # anatomical palm side
        direction = _normalize(h_local[9])
        flex_axis = _normalize(np.cross(direction, normal)) * (1.0 if side == "right" else -1.0)
        candidate = flex_axis - np.dot(flex_axis, up) * up
        if np.linalg.norm(candidate) > 1e-3:
            bend_hand = _normalize(candidate)
    weight = float(np.clip((np.sin(bend_angle) - 0.15) / 0.25, 0.0, 1.0))
    fallback = bend_hand if bend_hand is not None else (prev_bend if prev_bend is not None else None)
    if fallback is None:
        fallback = _normalize(np.array([1.0, 0.0, 0.0]) - up[0] * up)  # bend forward
    if not np.all(np.isfinite(bend_arm)):
        weight = 0.0
        bend_arm = fallback
    bend = _normalize(weight * bend_arm + (1 - weight) * fallback)
    rot_s = np.stack([bend, -up, np.cross(bend, -up)], axis=-1)
    quat = matrix_to_quat(rot_s[None])[0]
    wrist_angle = np.nan
    if hand is not None:
        elbow_rot = chest_rot @ rot_s @ axis_angle_matrix([0, 0, 1], np.array([bend_angle]))[0]
        flex_axis_world = elbow_rot[:, 0]
        direction = hand[9] - hand[0]
        wrist_angle = float(signed_angle(_project(w - e, flex_axis_world), _project(direction, flex_axis_world),
                                         flex_axis_world)) + wrist_offset  # fmt: skip
    return quat, bend_angle, wrist_angle, bend


def retarget_upper_body(
    body: dict[str, np.ndarray],
    hands: dict[str, np.ndarray],
    fps: float,
    sigma: float = 1.0,
    data_root=None,
    torso: str = "vertical",
    arm_hands: dict[str, np.ndarray] | None = None,
) -> RetargetResult:
    """Body points {name: (T, 3)} and hand landmarks {side: (T, 21, 3)} in the humanoid frame
    (NaN where missing) -> the 76-column upper-body motion.

    ``arm_hands`` ({side: (T, 21, 3)}, e.g. :func:`pose_hands`): where a hand's landmarks are
    missing, what turns the wrist and a straight arm's bending plane (its points 0, 5, 9 and 17).

    ``torso``: how the chest is turned. 'vertical' (default): from the shoulder line only,
    upright otherwise; sign videos are framed at the waist and MediaPipe's hips there are
    guesses whose depth reads as a 15-35 degree forward lean on the six WLASL clips. 'hips':
    also pitch from the hips -> shoulders vector (exact on the model's own keypoints)."""
    model = upper_body_model(data_root)
    T = len(body["left_shoulder"])
    needed = ("left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist")
    body_ok = np.all([np.all(np.isfinite(body[n]), axis=-1) for n in needed], axis=0)
    if not body_ok.any():
        raise ValueError("no frame with both arms (shoulders, elbows, wrists) observed")
    hand_ok = {s: np.all(np.isfinite(hands[s]), axis=(-1, -2)) for s in ("left", "right")}
    hips_ok = np.all(np.isfinite(body["left_hip"]), -1) & np.all(np.isfinite(body["right_hip"]), -1)
    head_ok = np.all([np.all(np.isfinite(body[n]), -1) for n in ("nose", "left_ear", "right_ear")], axis=0)

    # Torso: right = shoulder line; up = hips -> shoulders (vertical where hips are unknown).
    shoulder_mid = (body["left_shoulder"] + body["right_shoulder"]) / 2
    hip_mid = (body["left_hip"] + body["right_hip"]) / 2
    right = body["right_shoulder"] - body["left_shoulder"]
    if torso == "hips":
        up = np.where(hips_ok[:, None], shoulder_mid - hip_mid, np.array([0.0, 1.0, 0.0]))
        chest_rot = model.chest_rotation(right, up)  # (T, 3, 3)
    elif torso == "vertical":
        # Only the shoulder line turns the chest (roll and yaw); upright means no pitch.
        chest_rot = _frame_from(right, np.array([0.0, 1.0, 0.0]))
    else:
        raise ValueError(f"torso={torso!r}: expected 'vertical' or 'hips'")
    chest_q = np.full((T, 4), np.nan)
    chest_q[body_ok] = matrix_to_quat(chest_rot[body_ok])

    neck_q = np.full((T, 4), np.nan)
    ok = head_ok & body_ok
    if ok.any():
        head = _head_frame({k: body[k][ok] for k in ("nose", "left_ear", "right_ear")})
        neck_rot = np.swapaxes(chest_rot[ok], 1, 2) @ head @ model.head_rest.T
        neck_q[ok] = matrix_to_quat(neck_rot)

    joints: dict[str, np.ndarray] = {}
    report: dict = {"frames": T, "body_frames": int(body_ok.sum()), "past_limits": {}}  # arms; fingers per hand
    report["depth_to_width"], warnings = depth_warning(body)  # implausible proportions, said on the terminal
    for side in ("right", "left"):
        side_joints, side_report, side_warnings = _retarget_arm(side, body, hands, body_ok, hand_ok, chest_rot,
                                                                model, sigma, (arm_hands or {}).get(side))
        joints.update(side_joints)
        report["past_limits"].update(side_report.pop("past_limits"))
        report.update(side_report)
        warnings += side_warnings
    joints["chest"] = smooth_quaternions(fill_gaps(chest_q)[0], sigma)
    if np.isfinite(neck_q).any():
        joints["neck"] = smooth_quaternions(fill_gaps(neck_q)[0], sigma)
    report["torso"] = torso
    report["head_frames"] = int(ok.sum())
    report["hip_frames"] = int(hips_ok.sum())
    report["warnings"] = warnings
    return RetargetResult(upper_body_frames(joints, T), 1.0 / fps, report)


def _retarget_arm(side: str, body: dict[str, np.ndarray], hands: dict[str, np.ndarray], body_ok: np.ndarray,
                  hand_ok: dict[str, np.ndarray], chest_rot: np.ndarray, model, sigma: float,
                  arm_hand: np.ndarray | None = None):
    """One arm of :func:`retarget_upper_body`: the shoulder, elbow and wrist solved frame by frame in
    the chest's frame (the hand's landmarks, else ``arm_hand``'s points, turn the wrist), the fingers
    from the hand's landmarks, gaps filled and smoothed, inside the joint limits. Returns its joints,
    its report entries (``past_limits`` among them) and warnings."""
    T = len(body_ok)
    arm_ok = (np.all(np.isfinite(arm_hand[:, ARM_HAND_POINTS]), axis=(-1, -2)) & ~hand_ok[side]
              if arm_hand is not None else np.zeros(T, dtype=bool))
    q = np.full((T, 4), np.nan)
    elbow = np.full(T, np.nan)
    wrist = np.full(T, np.nan)
    prev = None
    for t in np.flatnonzero(body_ok):
        hand = hands[side][t] if hand_ok[side][t] else (arm_hand[t] if arm_ok[t] else None)
        q[t], elbow[t], wrist[t], prev = _solve_arm(
            side, body[f"{side}_shoulder"][t], body[f"{side}_elbow"][t], body[f"{side}_wrist"][t],
            hand, chest_rot[t], prev, model.wrist_offset)  # fmt: skip
    prefix = side[0] + "_"
    try:
        fingers, hand_report = finger_angles(hands[side], model.hands[side], sigma)
    except ValueError as err:
        fingers = np.zeros((T, 15))
        hand_report = {"frames_observed": 0, "coverage": 0.0, "observed": False,
                       "note": f"{err}: fingers left open (0)"}  # fmt: skip
    warnings = list(hand_report.get("warnings", []))
    elbow_lim = model.kinematics.limits([f"{side}_elbow"])
    wrist_lim = model.kinematics.limits([f"{side}_wrist"])
    report = {f"{side}_hand": hand_report,
              f"{side}_elbow_outside_limits": round(_clip_report(elbow, *elbow_lim), 3),
              f"{side}_wrist_outside_limits": round(_clip_report(wrist, *wrist_lim), 3)}
    if arm_hand is not None:  # the frames whose wrist came from the hand's landmarks, and from the arm's points
        report[f"{side}_wrist_from"] = {"hand_landmarks": int((hand_ok[side] & body_ok).sum()),
                                        "pose_hand_points": int((arm_ok & body_ok).sum())}
    arm_lower, arm_upper = model.kinematics.limits([f"{side}_elbow", f"{side}_wrist"])
    report["past_limits"], arm_warnings = limit_warnings(np.stack([elbow, wrist], axis=1), arm_lower, arm_upper,
                                                         [f"{side}_elbow", f"{side}_wrist"])  # fmt: skip
    warnings += arm_warnings
    wrist_filled, wrist_seen = fill_gaps(wrist[:, None])
    if not wrist_seen.any():
        wrist_filled = np.zeros((T, 1))
    joints = {f"{side}_shoulder": smooth_quaternions(fill_gaps(q)[0], sigma),
              f"{side}_elbow": np.clip(smooth(fill_gaps(elbow[:, None])[0], sigma)[:, 0], *elbow_lim),
              f"{side}_wrist": np.clip(smooth(wrist_filled, sigma)[:, 0], *wrist_lim)}
    for k, name in enumerate(HAND_JOINTS):
        joints[prefix + name] = fingers[:, k]
    return joints, report, warnings


# ----------------------------------------------------------------------------- files


def dominant_side(world: np.ndarray) -> str:
    """The hand seen in more frames ('right' on a tie): the signer's dominant hand."""
    seen = {side: int(np.all(np.isfinite(world[:, off : off + 21]), axis=(1, 2)).sum())
            for side, off in (("left", H.LEFT_HAND_OFFSET), ("right", H.RIGHT_HAND_OFFSET))}  # fmt: skip
    return "left" if seen["left"] > seen["right"] else "right"


def retarget_video(
    keypoint_dir: str | os.PathLike,
    video_id: str | None = None,
    out_dir: str | os.PathLike | None = None,
    hand: str = "dominant",
    sigma: float = 1.0,
    data_root=None,
    torso: str = "vertical",
    landmark_filter=None,
    pose_hand_points: bool = False,
) -> dict:
    """Write ``<out>/hand/<id>.txt`` (23 columns) and ``<out>/upper_body/<id>.txt`` (76 columns)
    from a video's world landmarks: an extraction folder and a video id, or a ``.pose`` file with
    MediaPipe points (:mod:`aslexp.pose.landmarks`); returns a report. A part that cannot be made
    (no hand, no body; for a ``.pose``, a part the file does not have at all) is reported with its
    reason; the other part is still written. A hands-only file gives the hand motion, a body-only
    one the upper body (fingers open)."""
    from aslexp.pose.landmarks import load_world

    kdir = Path(keypoint_dir)
    out = Path(out_dir) if out_dir else (kdir.parent if kdir.suffix == ".pose" else kdir) / "motions"
    return retarget_landmarks(load_world(kdir, video_id), out, hand, sigma, data_root, torso, landmark_filter,
                              pose_hand_points)


def finger_columns(side: str) -> list[int]:
    """The columns (of the values without dt) of one hand's 15 finger angles in an upper-body motion."""
    columns, col = [], 7
    for name, width in UPPER_BODY_COLUMNS:
        if name.startswith(f"{side[0]}_") and name[2:] in HAND_JOINTS:
            columns.append(col)
        col += width
    return columns


def retarget_landmarks(landmarks, out_dir: str | os.PathLike, hand: str = "dominant", sigma: float = 1.0,
                       data_root=None, torso: str = "vertical", landmark_filter=None,
                       pose_hand_points: bool = False) -> dict:  # fmt: skip
    """:func:`retarget_video` on :class:`~aslexp.pose.landmarks.Landmarks` from any source (an
    extraction folder, a ``.pose``, a keypoint array). Each part's entry has a ``status``: ok (with
    its ``path`` and report, whose ``warnings`` name implausible joints and proportions), failed
    (``error``: why), or skipped (``error``: the input's kind never holds that part).

    ``landmark_filter`` (:class:`~aslexp.pose.landmark_filter.LandmarkFilter`; None: none) smooths
    the landmarks in time first; each hand's report says how still its held handshapes stay
    (``handshape_flicker``, over the frames where the unfiltered source hand holds its shape).
    ``pose_hand_points``: where a hand's landmarks are missing, Pose's wrist, index and pinky
    knuckles turn the upper body's wrist (:func:`pose_hands`; the report's ``<side>_wrist_from``)."""
    from aslexp.pose.landmark_filter import LandmarkFilter, held_handshape_flicker, still_frames

    out = Path(out_dir)
    raw, fps, video_id, missing = landmarks.world.astype(float), landmarks.fps, landmarks.video_id, landmarks.missing
    landmark_filter = landmark_filter or LandmarkFilter("none", 0.0, 2)
    world = landmark_filter.apply(raw, fps)

    def flicker(side: str, angles: np.ndarray) -> dict:
        offset = H.LEFT_HAND_OFFSET if side == "left" else H.RIGHT_HAND_OFFSET
        return held_handshape_flicker(angles, still_frames(raw[:, offset:offset + 21], fps))

    result: dict = {"video_id": video_id, "fps": fps, "frames": len(world),
                    "landmark_filter": {"kind": landmark_filter.kind, "window_s": landmark_filter.window,
                                        "order": landmark_filter.order}, "sigma": sigma, "pose_hand_points": bool(pose_hand_points)}
    if missing:
        result["unavailable"] = dict(missing)  # parts the input does not have, and why
    if landmarks.warnings:
        result["warnings"] = list(landmarks.warnings)
    result.update(getattr(landmarks, "record", {}))  # e.g. a Pose array's path, frame rate and lift
    side = dominant_side(world) if hand == "dominant" else hand
    offset = H.LEFT_HAND_OFFSET if side == "left" else H.RIGHT_HAND_OFFSET
    no_hand = hand == "dominant" and {"left_hand", "right_hand"} <= set(missing)  # else the dominant one is there
    which = "hand" if no_hand else f"{side} hand"
    try:
        if "hand" in landmarks.skip:
            raise _NotInInput(landmarks.skip["hand"])
        if no_hand:
            raise ValueError(f"{missing['left_hand']}; {missing['right_hand'].removeprefix('not in the file: ')} "
                             "(the hand motion needs one)")  # fmt: skip
        if f"{side}_hand" in missing:
            raise ValueError(f"{missing[f'{side}_hand']} (the hand motion needs it)")
        hand_kp = world[:, offset : offset + 21] @ MP_TO_HUMANOID.T
        motion = hand_motion_from_landmarks(hand_kp, fps, side, sigma, data_root)
        motion.report["handshape_flicker"] = flicker(side, motion.frames[:, 7:])
        path = motion.save(out / "hand" / f"{video_id}.txt")
        result["hand"] = {"status": "ok", "path": str(path), **motion.report}
    except _NotInInput as err:
        result["hand"] = {"status": "skipped", "reason": "not_in_input", "detail": str(err),
                          "error": f"{video_id}: hand: {err}"}  # fmt: skip
    except ValueError as err:
        result["hand"] = {"status": "failed", "reason": "no_hand", "error": f"{video_id}: {which}: {err}"}
    try:
        if "upper_body" in landmarks.skip:
            result["upper_body"] = {"status": "skipped", "reason": "not_in_input", "detail": landmarks.skip["upper_body"],
                                    "error": f"{video_id}: upper body: {landmarks.skip['upper_body']}"}  # fmt: skip
        elif "body" in missing:
            raise ValueError(f"{missing['body']} (the upper body needs both shoulders, elbows and wrists)")
        else:
            body, hands = humanoid_inputs_from_world(world)
            motion = retarget_upper_body(body, hands, fps, sigma, data_root, torso,
                                         pose_hands(world) if pose_hand_points else None)
            for side in ("right", "left"):
                if motion.report[f"{side}_hand"].get("frames_observed"):
                    motion.report[f"{side}_hand"]["handshape_flicker"] = flicker(
                        side, motion.frames[:, finger_columns(side)])
            path = motion.save(out / "upper_body" / f"{video_id}.txt")
            result["upper_body"] = {"status": "ok", "path": str(path), **motion.report}
            _mark_plausibility(result["upper_body"], body, fps, landmarks)
    except ValueError as err:
        result["upper_body"] = {"status": "failed", "reason": "no_body", "error": f"{video_id}: upper body: {err}"}
    report_path = out / "reports" / f"{video_id}.json"
    report_path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(report_path, json.dumps(result, indent=1))  # whole or not at all (a full disk, Ctrl-C)
    return result


class _NotInInput(Exception):
    """A part the input's kind never holds (a Pose array's hands): not made, not failed."""


def _mark_plausibility(report: dict, body: dict[str, np.ndarray], fps: float, landmarks) -> None:
    """The upper body's ``plausibility`` (:func:`motion_plausibility`), its jump warnings with the
    others; the arms' seen share from a Pose array's visibility, else the frames with both arms."""
    record = getattr(landmarks, "record", {}).get("pose_array", {})
    shares = record.get("arm_seen_share")
    seen = max(shares.values()) if shares else report["body_frames"] / max(report["frames"], 1)
    check = motion_plausibility(report, body, fps, seen)
    report["warnings"] = report.get("warnings", []) + check.pop("warnings")
    if "out_of_view" in check["reasons"]:
        report["warnings"].append(f"out of view: {check['reasons']['out_of_view']}: the rest is MediaPipe's guess")
    report["plausibility"] = check
