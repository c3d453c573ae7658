"""MediaPipe Pose arrays ((T, 132) or (T, 33, 4)) lifted to metres, for the upper-body motion.

What for: the shared data's 291 WLASL clips are MediaPipe Pose arrays (33 body landmarks x (x, y,
z, visibility), no fingers) of another project; this turns each into the :class:`Landmarks` that
retargeting reads, so that each becomes a real sign for the upper body to perform (the fingers held
at rest, marked unobserved).

The arrays hold image coordinates, not MediaPipe's world metres: x / frame width, y / frame height
and a relative z, nominally on x's scale. Three things are unknown, and fixed from the body itself:

- The frame's aspect (height / width): the arrays hold no frame size and WLASL's clips come from
  many sites (1280x720, 640x480, 360x240 ...). ``--frame-size`` gives it for a batch of one size;
  else it is fitted per clip (below).
- The depth's scale: MediaPipe Pose's image z is on another scale than x (taken as it is, the
  arms come out 2-4 shoulder widths deep: :func:`aslexp.pose.retarget.depth_warning`). Fitted.
- The unit: the median shoulder width is 0.36 m (``SHOULDER_WIDTH_M``, as for a ``.pose`` lifted
  from its image). The angles retargeting reads do not depend on it.

The fit: in shoulder widths, an arm segment's length is fixed by the body. With the thesis
humanoid's own proportions (upper arm 0.75, forearm 0.71 shoulder widths, read from its URDF) each
observed segment (dx, dy, dz) in every frame says ``dx^2 + a^2 dy^2 + k^2 dz^2 = L^2``: linear in
the aspect squared ``a^2`` and the depth scale squared ``k^2``, solved by non-negative least squares
over the four segments, each from the frames where MediaPipe saw its ends and both shoulders
(visibility >= ``VISIBILITY_MIN``); the shoulder width itself is measured with the current (a, k),
a few rounds. So the lifted arms have the model's proportions, whose directions the retargeter
turns into angles; on a thesis sign laid out so (tests/extraction/test_pose_arrays.py) the fit
finds the aspect and the depth's scale to 2 %. Measured on the 291 clips: k is about 0.2
(MediaPipe's image z about 5 times x's scale); the aspect 0.45-0.55 on the 16:9 sites (0.5625
exactly: aslu 0.52, scott 0.55, startasl 0.49, aslbrick 0.49, valencia-asl 0.47, signschool 0.45),
0.53 on asl5200's 360x240 (0.667): people's arms are a little longer than the model's over the
shoulder landmarks, so the fit reads 5-20 % low. 38 clips fall back (FALLBACK_*: an arm never
seen, or the fit out of its range), said in the report.
"""

from __future__ import annotations

import os
from functools import lru_cache
from pathlib import Path

import numpy as np

from aslexp.errors import DataError
from aslexp.keypoints import holistic as H
from aslexp.pose.landmarks import Landmarks, landmarks_from_array

POSE_ARRAY_VALUES = H.NUM_POSE * 4  # 33 landmarks x (x, y, z, visibility)
SHOULDER_WIDTH_M = 0.36
# MediaPipe's own drawing utilities leave out landmarks below 0.5 visibility: guessed, not seen.
VISIBILITY_MIN = 0.5
HAND_POINTS = ("pinky", "index", "thumb")  # Pose's knuckles of each hand
ARMS = ("left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist")
SEGMENTS = (("left_shoulder", "left_elbow"), ("left_elbow", "left_wrist"),
            ("right_shoulder", "right_elbow"), ("right_elbow", "right_wrist"))  # fmt: skip
FIT_ROUNDS = 5
FIT_MIN_FRAMES = 5  # fewer frames with both arms seen: no fit, the fallback below
# Where the fit has too little to go on: the median fit of the 291 WLASL clips on the 16:9 sites,
# the most common frame (aspect) and the depth scale the fit finds on most clips.
FALLBACK_ASPECT = 9 / 16
FALLBACK_DEPTH_SCALE = 0.2
ASPECT_RANGE = (0.3, 1.5)  # portrait 2:3 to 10:3: outside it the fit has gone wrong
DEPTH_SCALE_RANGE = (0.02, 1.5)


@lru_cache(maxsize=4)
def _arm_proportions(data_root: str | None) -> dict[tuple[str, str], float]:
    from aslexp.pose.retarget import _body_points, upper_body_kinematics

    kin = upper_body_kinematics(data_root)
    points = {name: p[0] for name, p in _body_points(kin, kin.forward({}, "base", 1)).items()}
    width = np.linalg.norm(points["right_shoulder"] - points["left_shoulder"])
    return {(a, b): float(np.linalg.norm(points[b] - points[a]) / width) for a, b in SEGMENTS}


def arm_proportions(data_root=None) -> dict[tuple[str, str], float]:
    """Each arm segment's length over the shoulder width, of the thesis humanoid (its URDF)."""
    return _arm_proportions(None if data_root is None else str(data_root))


def fit_aspect_and_depth(points: np.ndarray, seen: np.ndarray, lengths: dict, aspect: float | None = None
                         ) -> tuple[float, float, int]:  # fmt: skip
    """(aspect, depth scale, frames used) for (T, 33, 3) normalised points, each segment from the
    frames where ``seen`` (T, 33) holds for its two ends and both shoulders (module doc); ``aspect``
    given (a known frame size): only the depth is fitted. Falls back to FALLBACK_* (frames used 0)
    where there are too few frames or the fit leaves its range."""
    from scipy.optimize import nnls

    index = {name: H.POSE_NAMES.index(name) for name in ARMS}
    shoulders = seen[:, index["left_shoulder"]] & seen[:, index["right_shoulder"]]
    frames = {(s, e): shoulders & seen[:, index[s]] & seen[:, index[e]] for s, e in lengths}
    used = int(np.any(list(frames.values()), axis=0).sum())
    if used < FIT_MIN_FRAMES:
        return (aspect or FALLBACK_ASPECT), FALLBACK_DEPTH_SCALE, 0
    a, k = aspect or FALLBACK_ASPECT, FALLBACK_DEPTH_SCALE
    for _ in range(FIT_ROUNDS):
        scale = np.array([1.0, a, k])
        p = points[shoulders]
        width = np.median(np.linalg.norm((p[:, index["right_shoulder"]] - p[:, index["left_shoulder"]]) * scale, axis=1))
        rows, target = [], []
        for (s, e), length in lengths.items():
            p = points[frames[(s, e)]]
            d = (p[:, index[e]] - p[:, index[s]]) / width
            if aspect is None:
                rows.append(np.stack([d[:, 1] ** 2, d[:, 2] ** 2], axis=1))
                target.append(length**2 - d[:, 0] ** 2)
            else:
                rows.append(d[:, 2:3] ** 2)
                target.append(length**2 - d[:, 0] ** 2 - (aspect * d[:, 1]) ** 2)
        solution = nnls(np.concatenate(rows), np.concatenate(target))[0]  # squares: never negative
        if aspect is None:
            a = float(np.sqrt(solution[0]))
        k = float(np.sqrt(solution[-1]))
        if not (ASPECT_RANGE[0] <= a <= ASPECT_RANGE[1] and DEPTH_SCALE_RANGE[0] <= k <= DEPTH_SCALE_RANGE[1]):
            return (aspect or FALLBACK_ASPECT), FALLBACK_DEPTH_SCALE, 0
    return a, k, used


def lift_pose_array(array: np.ndarray, frame_size: tuple[int, int] | None = None, data_root=None
                    ) -> tuple[np.ndarray, np.ndarray, dict]:  # fmt: skip
    """(T, 132) or (T, 33, 4) MediaPipe Pose (normalised image) -> (T, 33, 3) metres in MediaPipe's
    world axes (x right, y down, z away from the camera; NaN in frames without a person: all
    zeros), the (T, 33) visibility, and the record of the lift (aspect, depth scale, where each
    comes from, the metres per shoulder width)."""
    points = np.asarray(array, dtype=float).reshape(len(array), H.NUM_POSE, 4)
    person = np.any(points != 0, axis=(1, 2)) & np.isfinite(points).all(axis=(1, 2))
    xyz = np.where(person[:, None, None], points[..., :3], np.nan)
    visibility = np.where(person[:, None], points[..., 3], np.nan)
    with np.errstate(invalid="ignore"):
        seen = person[:, None] & (visibility >= VISIBILITY_MIN)
    known = frame_size[1] / frame_size[0] if frame_size else None
    aspect, depth, used = fit_aspect_and_depth(xyz, seen, arm_proportions(data_root), known)
    lifted = xyz * np.array([1.0, aspect, depth])
    left, right = H.POSE_NAMES.index("left_shoulder"), H.POSE_NAMES.index("right_shoulder")
    widths = np.linalg.norm(lifted[:, right] - lifted[:, left], axis=-1)
    if not np.isfinite(widths).any():
        raise ValueError("no frame with a person (every frame all zeros)")
    metres_per_unit = SHOULDER_WIDTH_M / float(np.nanmedian(widths))
    fitted = f"fitted to the thesis humanoid's arm proportions on {used} frames with an arm seen"
    fallback = f"too few frames with an arm seen (visibility >= {VISIBILITY_MIN}) or no fit: the fallback"
    record = {
        "method": "normalised image x, y * aspect, z * depth scale, in shoulder widths of 0.36 m "
                  "(aslexp.pose.body_arrays)",
        "aspect": round(aspect, 4),
        "aspect_from": f"--frame-size {frame_size[0]}x{frame_size[1]}" if frame_size else (fitted if used else fallback),
        "depth_scale": round(depth, 4),
        "depth_scale_from": fitted if used else fallback,
        "metres_per_unit": round(metres_per_unit, 4),
        "frames_with_person": int(person.sum()),
        "frames_fitted": used,
    }  # fmt: skip
    return (lifted * metres_per_unit).astype(np.float32), visibility, record


def landmarks_from_pose_array(path: str | os.PathLike, array: np.ndarray, fps: float, fps_from: str,
                              frame_size: tuple[int, int] | None = None, gloss: str | None = None,
                              data_root=None):  # fmt: skip
    """The :class:`~aslexp.pose.landmarks.Landmarks` of a MediaPipe Pose array: the body lifted
    (:func:`lift_pose_array`), both hands missing (the hand motion is not made, and the upper
    body's fingers stay at rest, marked unobserved), and the input's record for the report: its
    path, shape, frame rate and where that comes from, gloss, the lift and the arms' visibility."""
    path = Path(path)
    try:
        body, visibility, lift = lift_pose_array(array, frame_size, data_root)
    except ValueError as err:
        raise DataError(f"{path}: MediaPipe Pose array {tuple(array.shape)}: {err}") from None
    world = np.full((len(body), H.NUM_NODES, 3), np.nan, np.float32)
    world[:, : H.NUM_POSE] = body
    # Pose's own hand points (what retargeting.pose_hand_points turns the wrist with) only where seen
    hand_points = [H.POSE_NAMES.index(f"{side}_{name}") for side in ("left", "right") for name in HAND_POINTS]
    with np.errstate(invalid="ignore"):
        world[:, hand_points] = np.where((visibility[:, hand_points] >= VISIBILITY_MIN)[..., None],
                                         world[:, hand_points], np.nan)
    kind = "a MediaPipe Pose array (T, 132) holds no hand landmarks"
    missing = {"left_hand": f"not in the file: {kind}", "right_hand": f"not in the file: {kind}"}
    seen_share = {}
    for side in ("left", "right"):
        arm = [H.POSE_NAMES.index(f"{side}_{part}") for part in ("shoulder", "elbow", "wrist")]
        with np.errstate(invalid="ignore"):
            seen_share[side] = round(float(np.all(visibility[:, arm] >= VISIBILITY_MIN, axis=1).mean()), 3)
    record = {"pose_array": {
        "path": str(path), "shape": list(array.shape), "kind": "MediaPipe Pose (33 body landmarks x (x, y, z, "
        "visibility), normalised image coordinates)", "fps": float(fps), "fps_from": fps_from,
        **({"gloss": gloss} if gloss else {}), "lift": lift,
        # per arm, the share of frames with its shoulder, elbow and wrist seen (visibility >= VISIBILITY_MIN)
        "arm_seen_share": seen_share,
        "fingers": "not observed: held at rest (0 rad, the model's open hand)",
        "hand_points": f"Pose's pinky, index and thumb knuckles below visibility {VISIBILITY_MIN}: left out",
    }}  # fmt: skip
    return Landmarks(world, float(fps), path.stem, missing, skip={"hand": kind}, record=record)


def is_pose_array(shape: tuple[int, ...]) -> bool:
    """(T, 132) or (T, 33, 4): a MediaPipe Pose array."""
    return (len(shape) == 2 and shape[1] == POSE_ARRAY_VALUES) or tuple(shape[1:]) == (H.NUM_POSE, 4)


def landmarks_from_keypoint_array(path: str | os.PathLike, frame_size: tuple[int, int] | None = None,
                                  fps: float = 25.0, fps_from: str | None = None, gloss: str | None = None,
                                  data_root=None, **hand_options) -> Landmarks:  # fmt: skip
    """Any keypoint array retargeting reads: a MediaPipe Pose array here (:func:`landmarks_from_pose_array`),
    the rest by :func:`aslexp.pose.landmarks.landmarks_from_array` (``hand_options``: its ``hand``,
    ``hand_order``, ``mirrored``); a one-line DataError for a file that is no array."""
    path = Path(path)
    try:
        array = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as error:
        raise DataError(f"{path}: not a readable .npy array ({error})") from None
    if array.dtype.kind in "iuf" and len(array) and is_pose_array(array.shape):
        return landmarks_from_pose_array(path, array, fps, fps_from or f"--fps {fps:g}", frame_size, gloss, data_root)
    return landmarks_from_array(path, frame_size, fps, **hand_options)


def wlasl_instances(wlasl_json: str | os.PathLike) -> dict[str, dict]:
    """video id -> {'gloss', 'fps'} from a WLASL json (``WLASL_v0.3.json``: a list of glosses,
    each with its instances)."""
    import json

    path = Path(wlasl_json)
    try:
        entries = json.loads(path.read_text())
        return {str(i["video_id"]): {"gloss": e["gloss"], "fps": i.get("fps")} for e in entries
                for i in e["instances"]}  # fmt: skip
    except (OSError, ValueError, KeyError, TypeError) as err:
        raise DataError(f"{path}: not a WLASL json (a list of {{gloss, instances: [{{video_id, fps}}]}}): "
                        f"{err}") from None
