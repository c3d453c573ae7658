"""Metric landmarks for retargeting, from an extraction folder or from a ``.pose`` file.

- ``<folder>/world/<id>.npy`` (``aslexp extract``): MediaPipe's world pose and metric hands.
- a ``.pose`` with MediaPipe points, found by name (:func:`aslexp.keypoints.posefile.holistic_arrays`;
  whatever of the body and the two hands is there): the ``POSE_WORLD_LANDMARKS`` component
  (metres, pose-format's x*width, y*height scaling undone) and, in files aslexp wrote, its metric
  hand components; where a file has no metric hand (files from pose-format's own
  ``video_to_pose``), each image hand is scaled to an adult hand and set on the world wrist, as
  the extraction worker does when MediaPipe Hands misses a hand (with its wrist at the origin
  where the body wrist is unknown, e.g. in a hands-only file: the hand motion reads only the
  hand's shape). A file without a world component is lifted from the image (pixels, MediaPipe's
  z on the x scale) and scaled so that the median shoulder width is 0.36 m: the angles
  retargeting reads do not depend on that scale, only on the image-space depth MediaPipe guessed.
- a keypoint array (``.npy``), by its shape (:func:`landmarks_from_array`): MediaPipe Hands'
  ``(T, 126)`` or ``(T, 42, 3)`` (two hands x 21 landmarks x (x, y, z), normalised image
  coordinates, the signer's left hand first as the ``mediapipe_hands`` layout reads them, a hand
  not found all zeros), one hand ``(T, 63)`` / ``(T, 21, 3)`` with its side given, or ``aslexp
  extract``'s ``(T, 75, 4)`` with its ``world/<id>.npy`` beside it. Image hands become metric as
  the extraction worker makes them when MediaPipe Hands misses a hand (pixels from the frame size,
  scaled to an adult hand; :func:`aslexp.pose.mediapipe_worker.image_hand_to_world`); hand arrays
  hold no body, so they give the hand motion only (the upper body is ``skip``: not made, said why).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from aslexp.errors import DataError
from aslexp.keypoints import holistic as H
from aslexp.pose.mediapipe_worker import image_hand_to_world

SHOULDER_WIDTH_M = 0.36
SIDES = (("left", H.LEFT_HAND_OFFSET, 15), ("right", H.RIGHT_HAND_OFFSET, 16))  # hand offset, pose wrist


@dataclass
class Landmarks:
    """What retargeting reads: (T, 75, 3) metres in MediaPipe world axes (NaN where missing), the
    fps, the video id, and why a part is not in the source at all ('body', 'left_hand',
    'right_hand' -> reason; ``.pose`` files and one-hand arrays lack parts)."""

    world: np.ndarray
    fps: float
    video_id: str
    missing: dict[str, str] = field(default_factory=dict)
    # Motions ('hand', 'upper_body') this kind of input can never give -> why: not made, not failed.
    skip: dict[str, str] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)  # about the input, said with its motions
    # What the input says about itself (a Pose array's path, frame rate, lift): merged into the report.
    record: dict = field(default_factory=dict)


def world_from_pose_file(path: str | os.PathLike) -> tuple[np.ndarray, float]:
    """(T, 75, 3) metres in MediaPipe world axes (NaN where missing) and the fps of a ``.pose``."""
    landmarks = landmarks_from_pose_file(path)
    return landmarks.world, landmarks.fps


def landmarks_from_pose_file(path: str | os.PathLike) -> Landmarks:
    """The :class:`Landmarks` of a ``.pose`` (a file without any MediaPipe part is a one-line
    DataError naming it and what is needed)."""
    from aslexp.keypoints.posefile import holistic_arrays

    pose = holistic_arrays(path)
    image, width, height = pose.keypoints, pose.width, pose.height
    if pose.world is not None:
        world = pose.world.astype(float)
    else:
        pixels = image[..., :3].astype(float) * np.array([width, height, width])
        world = np.full(pixels.shape, np.nan)
        shoulders = np.linalg.norm(pixels[:, 11] - pixels[:, 12], axis=-1)
        if np.isfinite(shoulders).any():
            world = pixels * (SHOULDER_WIDTH_M / np.nanmedian(shoulders))
        elif "body" not in pose.missing:
            pose.missing["body"] = "no frame with both shoulders in the file: no scale for the image landmarks"
    for _, offset, wrist in SIDES:
        hand = slice(offset, offset + H.NUM_HAND)
        for t in np.flatnonzero(~np.isfinite(world[:, offset, 0]) & np.isfinite(image[:, offset, 0])):
            local = image_hand_to_world(image[t, hand], width, height)
            origin = world[t, wrist] if np.isfinite(world[t, wrist]).all() else np.zeros(3)
            world[t, hand] = local - local[0] + origin
    return Landmarks(world.astype(np.float32), pose.fps, Path(path).stem, pose.missing)


def load_world(source: str | os.PathLike, video_id: str | None = None) -> Landmarks:
    """World landmarks, fps, video id (and, for a ``.pose``, the parts it lacks) from an
    extraction folder (with ``video_id``) or a ``.pose`` file (the id is its stem)."""
    source = Path(source)
    if source.suffix == ".pose":
        landmarks = landmarks_from_pose_file(source)
        landmarks.video_id = video_id or landmarks.video_id
        return landmarks
    if video_id is None:
        raise ValueError(f"{source}: an extraction folder needs a video id")
    status_path = source / "status" / f"{video_id}.json"
    world_path = source / "world" / f"{video_id}.npy"
    if not world_path.is_file():
        raise FileNotFoundError(f"{world_path}: no world landmarks (extract the video first)")
    status = json.loads(status_path.read_text()) if status_path.is_file() else {}
    return Landmarks(np.load(world_path).astype(float), float(status.get("fps") or 25.0), video_id)


# ----------------------------------------------------------------------------- keypoint arrays

ARRAY_KINDS = ("(T, 126) or (T, 42, 3) MediaPipe Hands (two hands x 21 landmarks x (x, y, z), the signer's "
               "left hand first, a hand not found all zeros); (T, 63) or (T, 21, 3) one hand, with --hand "
               "right|left; (T, 132) or (T, 33, 4) MediaPipe Pose (body only); (T, 75, 4) aslexp extract's arrays "
               "with world/<id>.npy beside")  # fmt: skip


class NeedsOption(DataError):
    """A keypoint array that cannot be read without an option the command line lacks: the same for
    every such file of a batch, so the command stops at the first (bad input, exit 2)."""


def parse_frame_size(text: str) -> tuple[int, int]:
    """'WIDTHxHEIGHT' (pixels) -> (width, height); a ValueError saying what is expected."""
    try:
        width, height = (int(part) for part in text.lower().split("x"))
    except ValueError:
        raise ValueError(f"frame size {text!r}: expected WIDTHxHEIGHT in pixels, e.g. 640x480") from None
    if width <= 0 or height <= 0:
        raise ValueError(f"frame size {text!r}: expected positive WIDTHxHEIGHT, e.g. 640x480")
    return width, height


def landmarks_from_array(path: str | os.PathLike, frame_size: tuple[int, int] | None = None, fps: float = 25.0,
                         hand: str = "dominant", hand_order: str = "left_right",
                         mirrored: bool = False) -> Landmarks:  # fmt: skip
    """The :class:`Landmarks` of a keypoint array (module doc), or a one-line DataError naming the
    file, its shape and what is needed. ``frame_size`` (width, height in pixels) turns normalised
    hand coordinates into the hand's own proportions (x / width and y / height differ by the
    aspect ratio); ``fps`` is the array's frame rate (arrays do not hold one); ``hand`` the side of
    a one-hand array; ``hand_order`` and ``mirrored`` as ``pose.options`` of ``pose=mediapipe_hands``
    (:mod:`aslexp.keypoints.hands`). MediaPipe Pose arrays ``(T, 132)`` are lifted by
    :func:`aslexp.pose.body_arrays.landmarks_from_keypoint_array`, which reads every kind."""
    from aslexp.keypoints.hands import (
        HAND_ORDERS,
        assign_sides,
        detection_order_warning,
        handedness_path,
        order_fingerprint,
        read_handedness,
    )

    path = Path(path)
    try:
        array = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError) as error:
        raise DataError(f"{path}: not a readable .npy array ({error})") from None
    shape, video_id = tuple(array.shape), path.stem
    if array.dtype.kind not in "iuf" or array.ndim not in (2, 3) or not len(array):
        raise DataError(f"{path}: array of shape {shape} and dtype {array.dtype}; expected {ARRAY_KINDS}")
    flat = array.reshape(len(array), -1).astype(np.float64)
    if flat.shape[1] == H.NUM_NODES * 4:  # aslexp extract's own: its metric world beside it
        world_path = path.parent / "world" / path.name
        if not world_path.is_file():
            raise DataError(f"{path}: MediaPipe Holistic arrays {shape} without their metric landmarks "
                            f"{world_path} (aslexp extract writes both); give its .pose (--format pose) or "
                            "extract the video again")  # fmt: skip
        return load_world(path.parent, video_id)
    sides = {2 * H.NUM_HAND * 3: ("left", "right"), H.NUM_HAND * 3: (hand,)}.get(flat.shape[1])
    if sides is None or (array.ndim == 3 and array.shape[2] != 3):
        extra = " (MediaPipe Pose: a body without hand landmarks)" if flat.shape[1] == H.NUM_POSE * 4 else ""
        raise DataError(f"{path}: array of shape {shape}{extra}; retargeting reads {ARRAY_KINDS}")
    if sides == ("dominant",):
        raise NeedsOption(f"{path}: one hand {shape} without its side: add --hand right or --hand left")
    if frame_size is None:
        raise NeedsOption(f"{path}: hand landmarks {shape} in normalised image coordinates need the video's "
                          "frame size for the hand's proportions (x is divided by the width, y by the height): "
                          "add --frame-size WIDTHxHEIGHT, e.g. --frame-size 640x480")  # fmt: skip
    if hand_order not in HAND_ORDERS:
        raise DataError(f"{path}: hand order {hand_order!r}; expected one of {list(HAND_ORDERS)}")
    width, height = frame_size
    clip = flat.reshape(len(flat), len(sides) * H.NUM_HAND, 3)
    warnings: list[str] = []
    if len(sides) == 2 and hand_order == "detection":
        labels_path = handedness_path(path)
        labels = read_handedness(labels_path, len(clip)) if labels_path.is_file() else None
        clip = assign_sides(clip, labels, mirrored=mirrored)[0]
    elif len(sides) == 2:
        line = detection_order_warning({video_id: order_fingerprint(clip)})
        if line:  # left_right read from a detection-order file mixes the two hands within the clip
            warnings.append(line.replace("use pose.options.hand_order=detection", "add --hand-order detection"))
    present = np.any(np.isfinite(clip) & (clip != 0), axis=2)  # (T, V): a landmark all zeros was not found
    world = np.full((len(clip), H.NUM_NODES, 3), np.nan)
    missing = {}
    for k, side in enumerate(sides):
        hand_points = clip[:, k * H.NUM_HAND : (k + 1) * H.NUM_HAND]
        offset = H.LEFT_HAND_OFFSET if side == "left" else H.RIGHT_HAND_OFFSET
        found = present[:, k * H.NUM_HAND : (k + 1) * H.NUM_HAND].all(axis=1)  # all 21 landmarks
        for t in np.flatnonzero(found):
            world[t, offset : offset + H.NUM_HAND] = image_hand_to_world(hand_points[t], width, height)
    for side in ("left", "right"):
        if side not in sides:
            missing[f"{side}_hand"] = f"not in the file: {path.name} holds one hand, the {sides[0]} (--hand)"
    kind = "a MediaPipe Hands array (T, 126)" if len(sides) == 2 else "a one-hand array (T, 63)"
    missing["body"] = f"not in the file: {kind} holds no body"
    return Landmarks(world.astype(np.float32), float(fps), video_id, missing,
                     skip={"upper_body": f"{kind} holds no body"}, warnings=warnings)  # fmt: skip
