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
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from aslexp.keypoints import holistic as H
from aslexp.pose.mediapipe_worker import image_hand_to_world

SHOULDER_WIDTH_M = 0.36
SIDES = (("left", H.LEFT_HAND_OFFSET, 15), ("right", H.RIGHT_HAND_OFFSET, 16))  # hand offset, pose wrist


@dataclass
class Landmarks:
    """What retargeting reads: (T, 75, 3) metres in MediaPipe world axes (NaN where missing), the
    fps, the video id, and why a part is not in the source at all ('body', 'left_hand',
    'right_hand' -> reason; only ``.pose`` files lack parts)."""

    world: np.ndarray
    fps: float
    video_id: str
    missing: dict[str, str] = field(default_factory=dict)


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
