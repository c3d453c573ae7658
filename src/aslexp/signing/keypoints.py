"""A performance in its source's keypoints: joint positions -> the engine's body -> MediaPipe points
in the source video's image frame (:mod:`aslexp.pose.source_frame` has the geometry).

Each step's joint positions are posed kinematically on the environment's reference body (the
engine's own, never stepped) and its link frames read back, so the points are the simulated
body's, whatever builds it (engine, URDF, proportions). The body frame is the root link's: a
fixed or pinned root is where the reference holds it, and a free root's drift (not recorded in a
trajectory) is not in the points.

:class:`SigningSource` is what a motion made by ``aslexp extract --motions`` says of its source
(its report: the keypoint file, the camera, the retargeting error); a motion without one (the
thesis' files, a motion made elsewhere) has none, and :meth:`SigningSource.for_motion` says why.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

from aslexp.errors import DataError
from aslexp.pose.retarget import Kinematics
from aslexp.pose.source_frame import (
    ROOT_LINK,
    SourceCamera,
    SourceImage,
    link_poses_in_body_frame,
    load_source_image,
    model_points,
    source_video,
)

NEEDED_JOINTS = ("left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist",
                 "neck", "r_index_prox", "l_index_prox")  # fmt: skip


@lru_cache(maxsize=8)
def _kinematics(urdf: str) -> Kinematics:
    return Kinematics.from_urdf(urdf)


def body_kinematics(urdf: str | os.PathLike) -> Kinematics:
    """The joint table of a body's URDF (which link each joint moves); a body without the upper
    body's arms, head and hands is a ValueError saying what is missing."""
    kinematics = _kinematics(str(urdf))
    missing = [name for name in NEEDED_JOINTS if name not in kinematics.joints]
    if missing:
        raise ValueError(f"{urdf}: no joints {missing}: the source's keypoints need the upper-body humanoid "
                         "(arms, head and both hands)")  # fmt: skip
    return kinematics


def performance_points(env: Any, q: np.ndarray) -> np.ndarray:
    """(T, 75, 3) body-frame MediaPipe points of the joint positions ``q`` (T, motion layout), posed
    on ``env.ref`` (it is left in the last pose; the env re-poses it every step)."""
    kinematics = body_kinematics(env.urdf)
    ref = env.ref
    states, bases = [], []
    for row in np.asarray(q, dtype=float):
        if not np.all(np.isfinite(row)):  # a simulation that blew up: no points (NaN), the engine never fed it
            states.append(np.full((ref.num_links, 13), np.nan))
            bases.append(np.full(7, np.nan))
            continue
        ref.set_state(row)
        states.append(ref.link_states(velocities=False))
        bases.append(np.concatenate(ref.base_state()[:2]))
    states = np.stack(states)
    names = list(ref.link_names)
    if ROOT_LINK not in names:  # an engine that lists the root as its base: the base frame is the root's
        states = np.concatenate([np.stack(bases)[:, None], states], axis=1)
        names = [ROOT_LINK, *names]
    poses = link_poses_in_body_frame(names, states, float(env.body_spec.global_scaling))
    return model_points(poses, kinematics)


@dataclass
class SigningSource:
    """A motion's source keypoints and the camera that puts the model in their image."""

    motion: Path
    report: Path
    image: SourceImage
    camera: SourceCamera
    retargeting_error: dict
    video: dict | None = None  # the source video (source_frame.source_video's record), when one is known

    @classmethod
    def for_motion(cls, motion_path: str | os.PathLike | None) -> tuple["SigningSource | None", str]:
        """The source of a motion file from its report (``<motions>/reports/<id>.json``, written by
        ``aslexp extract --motions``), or None and the one reason why there is none."""
        if not motion_path:
            return None, "the motion has no file (made in memory): no report names its source keypoints"
        motion = Path(motion_path)
        report = motion.parent.parent / "reports" / f"{motion.stem}.json"
        if not report.is_file():
            return None, (f"{motion} has no report beside it ({report}): only a motion made by `aslexp extract "
                          "--motions` names its source keypoints")  # fmt: skip
        try:
            values = json.loads(report.read_text())
        except (OSError, json.JSONDecodeError) as error:
            return None, f"{report}: not readable JSON ({error})"
        upper = values.get("upper_body") or {}
        source = values.get("source") or {}
        if "camera" not in upper or "keypoints" not in source:
            why = source.get("error") or "it names no source keypoint file and camera (made before extraction recorded them)"
            return None, f"{report}: {why}"
        keypoints = Path(source["keypoints"])
        if not keypoints.is_file():
            return None, f"{report}: its source keypoints {keypoints} are not there any more"
        try:
            size = (int(source["width"]), int(source["height"])) if "width" in source else None
            image = load_source_image(keypoints, size, float(source.get("fps") or 25.0))
            camera = SourceCamera.from_dict(upper["camera"], f"{report}: upper_body")
        except DataError as error:
            return None, str(error)
        video = source.get("video") or source_video(keypoints)  # a report from before it was recorded: the status
        return cls(motion, report, image, camera, dict(upper.get("retargeting_error") or {}), video), ""
