"""A body's points in the source video's image frame: where the person was, with the model's pose.

Retargeting keeps joint angles, not positions: the model has its own proportions and stands at
its own root. To read a motion (or a simulated performance) against the person's keypoints, this
module puts the model's points into the source's MediaPipe layout and normalised image frame:

- **Model points** (:func:`model_points`): MediaPipe Pose's 33 and MediaPipe Hands' 21 per hand, in
  aslexp's 75-node Holistic order, from the body's link frames (:data:`POSE_POINTS`, :data:`HAND_LINKS`):
  shoulders, elbows, wrists and hips are joint origins; the nose, ears, eyes and mouth are fixed
  points on the head (the neck link); the hand points are the finger links' origins and the
  fingertips (:data:`~aslexp.pose.retarget.FINGERTIP_OFFSET` past the distal link). The legs'
  points are not made (NaN): sign videos are framed at the waist and the model's legs are fixed.
  Coordinates are the **body frame**: the root link's frame in the URDF's own units.
- **The camera** (:class:`SourceCamera`): MediaPipe's world axes are the camera's (x to the image
  right, y down, z away), so the body frame turns into them by the inverse of retargeting's
  :data:`~aslexp.pose.retarget.MP_TO_HUMANOID`, then an orthographic projection: pixels =
  ``scale * (x, y) + origin``. ``scale`` (pixels per body unit) and ``origin`` (pixels) are
  fitted once per clip by least squares (:func:`fit_camera`) between the retargeted motion's arm
  points (shoulders, elbows, wrists) and the source's, over the frames where the source has them.
  ``z`` follows MediaPipe's convention (same scale as x, relative to the hips' midpoint for the
  body, to the wrist for each hand).
- **Errors** (:func:`frame_errors`): per part (body, each hand), the mean joint distance in the
  image plane over the frames and points the source has, in units of the source's mean shoulder
  width. On the retargeted motion played kinematically, frame by frame against the source, this
  is the **retargeting error** that ``aslexp extract --motions`` records in the motion's report.
"""

from __future__ import annotations

import json
import os
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from aslexp.keypoints import holistic as H
from aslexp.pose.retarget import (
    FINGER_CHAINS,
    FINGERS,
    FINGERTIP_OFFSET,
    HEAD_POINTS,
    MP_TO_HUMANOID,
    PHALANGES,
    Kinematics,
    upper_body_joints,
)
from aslexp.quaternion import matrices as quat_to_matrix  # written out: NaN in, NaN out

BODY_TO_IMAGE_AXES = MP_TO_HUMANOID.T  # body frame (y up, x forward, z right) -> MediaPipe's camera axes
ROOT_LINK = "root"  # the body frame: this link's frame (the pelvis; the motion's root)

# Face points on the head (the neck link frame, URDF units; the head is a 0.41 sphere at y = 0.7):
# the nose and ears retargeting reads (HEAD_POINTS), and eyes and mouth corners on the sphere's
# front for the viewer. Left is -z (z is the signer's right).
FACE_POINTS: dict[str, tuple[float, float, float]] = {
    **HEAD_POINTS,
    "left_eye_inner": (0.39, 0.78, -0.06), "left_eye": (0.38, 0.78, -0.12), "left_eye_outer": (0.36, 0.78, -0.18),
    "right_eye_inner": (0.39, 0.78, 0.06), "right_eye": (0.38, 0.78, 0.12), "right_eye_outer": (0.36, 0.78, 0.18),
    "mouth_left": (0.36, 0.52, -0.1), "mouth_right": (0.36, 0.52, 0.1),
}  # fmt: skip
# MediaPipe Pose's hand points, from the model hand's points (pinky and index knuckles, thumb joint).
POSE_HAND_POINTS = {"pinky": 17, "index": 5, "thumb": 2}

# What the scores and errors compare: the body points retargeting reads (the head's nose and ears,
# the arms), not the hips (waist-framed videos: MediaPipe guesses them, retargeting ignores them
# with its default upright torso) nor MediaPipe Pose's rough hand points (the hands are scored apart).
SCORED_BODY: tuple[int, ...] = tuple(H.POSE_NAMES.index(n) for n in (
    "nose", "left_ear", "right_ear", "left_shoulder", "right_shoulder", "left_elbow", "right_elbow",
    "left_wrist", "right_wrist"))  # fmt: skip
PARTS: dict[str, tuple[int, ...]] = {
    "body": SCORED_BODY,
    "left_hand": tuple(range(H.LEFT_HAND_OFFSET, H.LEFT_HAND_OFFSET + H.NUM_HAND)),
    "right_hand": tuple(range(H.RIGHT_HAND_OFFSET, H.RIGHT_HAND_OFFSET + H.NUM_HAND)),
}
FIT_NODES: tuple[int, ...] = tuple(H.POSE_NAMES.index(n) for n in (
    "left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist"))  # fmt: skip
LEFT_SHOULDER, RIGHT_SHOULDER = H.POSE_NAMES.index("left_shoulder"), H.POSE_NAMES.index("right_shoulder")
LEFT_HIP, RIGHT_HIP = H.POSE_NAMES.index("left_hip"), H.POSE_NAMES.index("right_hip")

LinkPoses = dict[str, tuple[np.ndarray, np.ndarray]]  # link -> (F, 3, 3) rotations, (F, 3) positions


# ----------------------------------------------------------------------------- model points


def model_points(poses: LinkPoses, kinematics: Kinematics) -> np.ndarray:
    """(F, 75, 3) MediaPipe Holistic points of the body (NaN for the legs) from its link frames
    (body frame, URDF units: :meth:`Kinematics.forward` from the root link, or an engine's links
    through :func:`link_poses_in_body_frame`); ``kinematics`` names each joint's link."""
    link = {name: joint.child for name, joint in kinematics.joints.items()}
    frames = len(next(iter(poses.values()))[1])
    out = np.full((frames, H.NUM_NODES, 3), np.nan)

    def at(link_name: str, offset=None) -> np.ndarray:
        rot, pos = poses[link_name]
        return pos if offset is None else pos + rot @ np.asarray(offset, dtype=float)

    for side in ("left", "right"):
        for part in ("shoulder", "elbow", "wrist", "hip"):
            out[:, H.POSE_NAMES.index(f"{side}_{part}")] = at(link[f"{side}_{part}"])
        offset = H.LEFT_HAND_OFFSET if side == "left" else H.RIGHT_HAND_OFFSET
        prefix = side[0] + "_"
        out[:, offset] = at(link[f"{side}_wrist"])
        for finger in FINGERS:
            chain = FINGER_CHAINS[finger]
            links = [link[f"{prefix}{finger}_{p}"] for p in PHALANGES]
            for k, name in enumerate(links):
                out[:, offset + chain[k]] = at(name)
            out[:, offset + chain[3]] = at(links[-1], FINGERTIP_OFFSET)
        for name, hand_point in POSE_HAND_POINTS.items():
            out[:, H.POSE_NAMES.index(f"{side}_{name}")] = out[:, offset + hand_point]
    for name, offset in FACE_POINTS.items():
        out[:, H.POSE_NAMES.index(name)] = at(link["neck"], offset)
    return out


def motion_points(frames: np.ndarray, kinematics: Kinematics) -> np.ndarray:
    """(F, 75, 3) model points of a 76-column upper-body motion's frames (F, 75), played kinematically
    on ``kinematics`` (the retargeting's own forward kinematics), in the body frame."""
    joints = upper_body_joints(frames)
    values = {k: v for k, v in joints.items() if k in kinematics.joints and kinematics.joints[k].type != "fixed"}
    poses = kinematics.forward(values, ROOT_LINK, len(frames))
    return model_points(poses, kinematics)


def link_poses_in_body_frame(link_names: list[str], states: np.ndarray, scale: float) -> LinkPoses:
    """An engine's link states (F, num_links, >= 7: world position, orientation w x y z; rows in
    ``link_names`` order) -> link frames in the body frame (the root link's, URDF units: world
    lengths / the body's ``global_scaling``)."""
    states = np.asarray(states, dtype=float)
    rot = quat_to_matrix(states[..., 3:7])  # (F, L, 3, 3)
    pos = states[..., 0:3]
    r = link_names.index(ROOT_LINK)
    root_rot_t = np.swapaxes(rot[:, r], -1, -2)  # (F, 3, 3)
    out: LinkPoses = {}
    for k, name in enumerate(link_names):
        out[name] = (root_rot_t @ rot[:, k], np.einsum("fij,fj->fi", root_rot_t, pos[:, k] - pos[:, r]) / scale)
    return out


# ----------------------------------------------------------------------------- the camera


@dataclass(frozen=True)
class SourceCamera:
    """Body frame -> the source's image: pixels = scale * (BODY_TO_IMAGE_AXES @ p)[:2] + origin,
    normalised by the frame's width and height as MediaPipe's image landmarks are."""

    width: int
    height: int
    scale: float  # pixels per body unit
    origin: tuple[float, float]  # pixels of the body frame's origin
    fitted_on: str = "shoulders, elbows, wrists"

    def project(self, points: np.ndarray) -> np.ndarray:
        """(F, 75, 3) body-frame points -> (F, 75, 4) image keypoints in aslexp's Holistic channels
        (x, y normalised; z MediaPipe's relative depth, same scale as x; visibility 1, NaN where a
        point is not made)."""
        q = np.asarray(points, dtype=float) @ BODY_TO_IMAGE_AXES.T
        out = np.empty(q.shape[:-1] + (4,))
        out[..., 0] = (self.scale * q[..., 0] + self.origin[0]) / self.width
        out[..., 1] = (self.scale * q[..., 1] + self.origin[1]) / self.height
        depth = self.scale * q[..., 2] / self.width
        hips = (depth[:, LEFT_HIP] + depth[:, RIGHT_HIP]) / 2
        out[:, : H.NUM_POSE, 2] = depth[:, : H.NUM_POSE] - hips[:, None]
        for offset in (H.LEFT_HAND_OFFSET, H.RIGHT_HAND_OFFSET):
            hand = slice(offset, offset + H.NUM_HAND)
            out[:, hand, 2] = depth[:, hand] - depth[:, offset, None]
        out[..., 3] = np.where(np.isfinite(q).all(axis=-1), 1.0, np.nan)
        out[~np.isfinite(q).all(axis=-1)] = np.nan
        return out

    def to_dict(self) -> dict:
        return {"kind": "orthographic", "body_to_image_axes": BODY_TO_IMAGE_AXES.tolist(),
                **{k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(self).items()}}  # fmt: skip

    @classmethod
    def from_dict(cls, values: dict, origin: str = "camera") -> "SourceCamera":
        from aslexp.errors import DataError

        try:
            return cls(int(values["width"]), int(values["height"]), float(values["scale"]),
                       (float(values["origin"][0]), float(values["origin"][1])),
                       str(values.get("fitted_on", "")))  # fmt: skip
        except (KeyError, TypeError, IndexError, ValueError) as error:
            raise DataError(f"{origin}: camera: expected width, height, scale and origin [u, v] ({error!r})") from None


def fit_camera(points: np.ndarray, source: np.ndarray, width: int, height: int,
               nodes: tuple[int, ...] = FIT_NODES) -> SourceCamera:  # fmt: skip
    """Least-squares scale and origin putting the body-frame ``points`` (F, 75, 3) on the source's
    image keypoints (F, 75, >= 2, normalised; NaN where missing) at the same frames, on ``nodes``."""
    q = np.asarray(points, dtype=float)[:, nodes] @ BODY_TO_IMAGE_AXES.T
    pixels = np.asarray(source, dtype=float)[:, nodes, :2] * np.array([width, height])
    seen = np.isfinite(pixels).all(axis=-1) & np.isfinite(q).all(axis=-1)
    if seen.sum() < 2:
        raise ValueError(f"the source has {int(seen.sum())} arm points (shoulders, elbows, wrists): "
                         "too few to place the model in its image")  # fmt: skip
    qx, qy, u, v = q[seen, 0], q[seen, 1], pixels[seen, 0], pixels[seen, 1]
    n = len(qx)
    design = np.zeros((2 * n, 3))
    design[:n, 0], design[:n, 1] = qx, 1.0
    design[n:, 0], design[n:, 2] = qy, 1.0
    solution = np.linalg.lstsq(design, np.concatenate([u, v]), rcond=None)[0]
    return SourceCamera(int(width), int(height), float(solution[0]), (float(solution[1]), float(solution[2])))


# ----------------------------------------------------------------------------- errors


def pixels(keypoints: np.ndarray, width: int, height: int) -> np.ndarray:
    """(F, V, >= 2) normalised image keypoints -> (F, V, 2) pixels (NaN stays NaN)."""
    return np.asarray(keypoints, dtype=float)[..., :2] * np.array([float(width), float(height)])


def shoulder_width(px: np.ndarray) -> float:
    """Mean shoulder distance (pixels) over the frames that have both shoulders, as pose-format's
    ``Pose.normalize`` measures it; NaN when no frame has them."""
    d = np.linalg.norm(px[:, LEFT_SHOULDER] - px[:, RIGHT_SHOULDER], axis=-1)
    return float(np.nanmean(d)) if np.isfinite(d).any() else float("nan")


def frame_errors(keypoints: np.ndarray, source: np.ndarray, width: int, height: int) -> dict:
    """Frame-by-frame (no time alignment) mean joint distance per part (:data:`PARTS`) between
    image keypoints and the source's at the same frames, over the points the source has, in the
    source's shoulder widths. A part the source never has: ``None`` with ``note``."""
    ours, theirs = pixels(keypoints, width, height), pixels(source, width, height)
    frames = min(len(ours), len(theirs))
    ours, theirs = ours[:frames], theirs[:frames]
    unit = shoulder_width(theirs)
    out: dict = {"units": "source shoulder widths", "frames": frames}
    for part, nodes in PARTS.items():
        d = np.linalg.norm(ours[:, nodes] - theirs[:, nodes], axis=-1)  # NaN where either lacks it
        if not np.isfinite(d).any():
            out[part] = {"mje": None, "note": "not in the source"}
            continue
        out[part] = {"mje": round(float(np.nanmean(d)) / unit, 5), "max": round(float(np.nanmax(d)) / unit, 5),
                     "frames": int(np.isfinite(d).any(axis=1).sum())}  # fmt: skip
    return out


# ----------------------------------------------------------------------------- the source's keypoints


@dataclass
class SourceImage:
    """A source's image keypoints: (T, 75, 4) normalised, aslexp's Holistic channels (NaN where
    missing), the frame size in pixels, the fps and the file they came from."""

    keypoints: np.ndarray
    width: int
    height: int
    fps: float
    path: Path


NOMINAL_WIDTH = 1000  # pixels of a source that holds no frame size (pose-format's own default width)


def load_source_image(path: str | os.PathLike, frame_size: tuple[int, int] | None = None,
                      fps: float = 25.0) -> SourceImage:  # fmt: skip
    """The image keypoints of a source: an extraction's ``<folder>/<id>.npy`` (its size and fps from
    ``<folder>/status/<id>.json``), a ``.pose`` with MediaPipe points (by name), or a MediaPipe Pose
    array ((T, 132) or (T, 33, 4), normalised; ``frame_size`` and ``fps`` are the array's, which it
    does not hold; a point below MediaPipe's 0.5 visibility counts as not seen). Another file is a
    one-line DataError naming it."""
    from aslexp.errors import DataError

    path = Path(path)
    if path.suffix == ".pose":
        from aslexp.keypoints.posefile import holistic_arrays

        pose = holistic_arrays(path)
        return SourceImage(pose.keypoints.astype(float), int(pose.width), int(pose.height), float(pose.fps), path)
    status_path = path.parent / "status" / f"{path.stem}.json"
    if path.suffix == ".npy" and status_path.is_file():
        status = json.loads(status_path.read_text())
        array = np.load(path).astype(float)
        if array.ndim != 3 or array.shape[1:] != (H.NUM_NODES, 4):
            raise DataError(f"{path}: source keypoints of shape {array.shape}; expected (T, {H.NUM_NODES}, 4)")
        return SourceImage(array, int(status["width"]), int(status["height"]), float(status.get("fps") or 25.0), path)
    if path.suffix == ".npy":
        from aslexp.pose.body_arrays import VISIBILITY_MIN, is_pose_array

        array = np.load(path, allow_pickle=False).astype(float)
        if is_pose_array(array.shape) and frame_size is not None:
            body = array.reshape(len(array), H.NUM_POSE, 4)
            keypoints = np.full((len(array), H.NUM_NODES, 4), np.nan)
            keypoints[:, : H.NUM_POSE] = np.where((body[..., 3:] >= VISIBILITY_MIN), body, np.nan)
            return SourceImage(keypoints, int(frame_size[0]), int(frame_size[1]), float(fps), path)
    raise DataError(f"{path}: source keypoints: expected a .pose, an extraction's <id>.npy with status/<id>.json "
                    "beside it, or a MediaPipe Pose array with its frame size")  # fmt: skip


def source_video(keypoints: str | os.PathLike) -> dict | None:
    """The video an extraction's keypoints came from, from ``status/<id>.json`` beside them (an
    ``aslexp extract`` output folder's ``<id>.npy`` or ``<id>.pose``): its path, the video frame
    (0-based) of the keypoints' first and its byte size then; None for keypoints no extraction
    of a video made (a MediaPipe Pose array, a .pose from elsewhere)."""
    path = Path(keypoints)
    status = path.parent / "status" / f"{path.stem}.json"
    try:
        values = json.loads(status.read_text())
        return {"path": str(values["video"]), "first_frame": int((values.get("frame_range") or [0])[0]),
                "bytes": values.get("video_size")}  # fmt: skip
    except (OSError, ValueError, KeyError, TypeError, IndexError):
        return None


def source_record(motion_frames: np.ndarray, source: SourceImage, kinematics: Kinematics) -> dict:
    """What a motion's report records of its source (``source``): the keypoint file, its size, the
    camera that puts the model in its image (``camera``) and the retargeting error (``error``:
    :func:`frame_errors` of the motion played kinematically against the source)."""
    points = motion_points(motion_frames, kinematics)
    camera = fit_camera(points, source.keypoints, source.width, source.height)
    error = frame_errors(camera.project(points), source.keypoints, source.width, source.height)
    return {"keypoints": str(source.path.resolve()), "width": source.width, "height": source.height,
            "fps": source.fps, "frames": len(source.keypoints), "camera": camera.to_dict(), "error": error}  # fmt: skip


def record_source(result: dict, keypoints: str | os.PathLike, out_dir: str | os.PathLike, data_root=None,
                  frame_size: tuple[int, int] | None = None) -> dict:  # fmt: skip
    """Add to a retargeting result (:func:`aslexp.pose.retarget.retarget_landmarks`'s) and its report
    ``<out_dir>/reports/<id>.json`` the source keypoint file (``source``) and, for an upper-body
    motion, the camera and the retargeting error (``upper_body.camera``, ``upper_body.retargeting_error``;
    :func:`source_record`). A source that cannot be read or placed says why in ``source.error``.
    A MediaPipe Pose array holds no frame size: ``frame_size`` (``--frame-size``), else the aspect its
    lift fitted (``pose_array.lift.aspect``) at NOMINAL_WIDTH pixels: the scores are in shoulder widths."""
    from aslexp.errors import DataError
    from aslexp.files import atomic_write_text
    from aslexp.pose.retarget import upper_body_kinematics
    from aslexp.sim.motion import load_motion

    upper = result.get("upper_body") or {}
    array = result.get("pose_array") or {}
    size_from = None
    if array and frame_size is None and "aspect" in array.get("lift", {}):
        frame_size = (NOMINAL_WIDTH, int(round(NOMINAL_WIDTH * float(array["lift"]["aspect"]))))
        size_from = f"the array's fitted aspect ({array['lift']['aspect']}) at {NOMINAL_WIDTH} pixels wide"
    try:
        image = load_source_image(keypoints, frame_size, float(result.get("fps") or 25.0))
        result["source"] = {"keypoints": str(image.path.resolve()), "width": image.width, "height": image.height,
                            "fps": image.fps, "frames": len(image.keypoints),
                            **({"size_from": size_from} if size_from else {})}  # fmt: skip
        video = source_video(image.path)
        if video is not None:  # the frames the keypoints were read from: a run draws the person on them
            result["source"]["video"] = video
        if upper.get("status") == "ok":
            frames = load_motion(upper["path"]).frames
            record = source_record(frames, image, upper_body_kinematics(data_root))
            upper["camera"], upper["retargeting_error"] = record["camera"], record["error"]
    except (DataError, OSError, ValueError, KeyError) as error:
        result["source"] = {"keypoints": str(Path(keypoints)), "error": f"{keypoints}: {error}"}
    atomic_write_text(Path(out_dir) / "reports" / f"{result['video_id']}.json", json.dumps(result, indent=1))
    return result
