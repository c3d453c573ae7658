"""A run's performance scored against the person it imitates (``signing`` in metrics.json) and
written as ``signing.pose`` in the run folder (docs/signing.md).

:func:`signing_metrics` takes the evaluation environment and recorded trajectories
(:func:`aslexp.rl.evaluate.evaluate` with ``record=True``, before any per-joint conversion):
the reference played kinematically (its ``q_ref``), and each stage's simulated body (``q_sim``),
each put in the source's keypoints (:mod:`aslexp.signing.keypoints`) and scored against the
source's own (:func:`aslexp.signing.scores.dtw_scores`). Only the first pass over the motion is
compared (an episode longer than the motion repeats a sign the person made once).
"""

from __future__ import annotations

import logging
import os
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from aslexp.signing.keypoints import SigningSource, body_kinematics, performance_points
from aslexp.signing.scores import dtw_scores

log = logging.getLogger(__name__)

SIGNING_POSE = "signing.pose"
SIGNING_VIDEO = "signing.mp4"  # and signing.gif: the person and the agent side by side
REFERENCE_STAGE = "reference"  # the retargeted reference played kinematically: what retargeting keeps


def one_pass(trajectory: Mapping[str, np.ndarray], duration: float, step: float) -> np.ndarray:
    """The steps of a trajectory within one pass over the motion from the episode's start (its
    first recorded time is one control ``step`` after it)."""
    times = np.asarray(trajectory["time"], dtype=float)
    return np.flatnonzero(times - (times[0] - step) <= duration + 1e-9)


def stage_keypoints(env: Any, source: SigningSource, q: np.ndarray) -> np.ndarray:
    """(T, 75, 4) image keypoints of joint positions ``q`` in the source's frame."""
    return source.camera.project(performance_points(env, q))


def score_trajectory(env: Any, trajectory: Mapping[str, np.ndarray], source: SigningSource,
                     joints: str = "q_sim") -> tuple[dict, np.ndarray]:  # fmt: skip
    """One stage's scores against the source and its keypoints: the trajectory's ``joints``
    (``q_sim``: the simulated body; ``q_ref``: the reference it was given) over one pass."""
    steps = one_pass(trajectory, float(env.reference.duration), 1.0 / float(env.spec_env.control_hz))
    keypoints = stage_keypoints(env, source, np.asarray(trajectory[joints])[steps])
    try:
        scores = dtw_scores(keypoints, source.image.keypoints, source.camera.width, source.camera.height)
    except ValueError as error:  # e.g. a simulation that blew up: no frame to normalise by
        scores = {"error": f"{joints}: {error}"}
    return {**scores, "steps": len(steps)}, keypoints


def _joint_positions(layout: Any) -> dict[str, int]:
    """Each one-value joint's place in a joint vector (``q``: the actuated joints in order, a
    spherical joint four values)."""
    out, at = {}, 0
    for joint in layout.joints:
        if joint.dof == 1:
            out[joint.name] = at
        at += joint.dof
    return out


def hand_on_body(body_env: Any, hand_env: Any, trajectory: Mapping[str, np.ndarray], side: str,
                 joints: str = "q_sim") -> tuple[np.ndarray, np.ndarray]:
    """A hand body's run worn by the upper body: the upper body's reference at the hand trajectory's
    times (one pass) with ``side``'s 15 finger joints set to the hand's ``joints``. Returns (steps
    of ``trajectory``, (T, upper-body joints)). The arm is the reference's for every stage, so two
    stages differ by their fingers alone."""
    steps = one_pass(trajectory, float(hand_env.reference.duration), 1.0 / float(hand_env.spec_env.control_hz))
    prefix = {"right": "r_", "left": "l_"}[side]
    worn, fingers = _joint_positions(body_env.sim.layout), _joint_positions(hand_env.sim.layout)
    missing = [name for name in fingers if prefix + name not in worn]
    if missing:
        raise ValueError(f"the upper body has no {prefix}<joint> for the hand's joints {missing}")
    times = np.asarray(trajectory["time"], dtype=float)[steps]
    q = np.array(body_env.reference.joints_many(np.minimum(times, float(body_env.reference.duration) - 1e-9)))
    hand = np.asarray(trajectory[joints], dtype=float)[steps]
    for name, column in fingers.items():
        q[:, worn[prefix + name]] = hand[:, column]
    return steps, q


def score_hand_trajectory(body_env: Any, hand_env: Any, trajectory: Mapping[str, np.ndarray],
                          source: SigningSource, side: str, joints: str = "q_sim") -> dict:
    """One stage of a hand body's run scored against the person's ``side`` hand, worn by the upper
    body (:func:`hand_on_body`): :func:`aslexp.signing.scores.hand_scores`."""
    from aslexp.signing.scores import hand_scores

    steps, q = hand_on_body(body_env, hand_env, trajectory, side, joints)
    keypoints = stage_keypoints(body_env, source, q)
    try:
        scores = hand_scores(keypoints, source.image.keypoints, source.camera.width, source.camera.height, side)
    except ValueError as error:  # e.g. a simulation that blew up
        scores = {"error": f"{joints}: {error}"}
    return {**scores, "steps": len(steps)}


def body_layout():
    """What the side-by-side video draws of aslexp's 75 Holistic points (aslexp.viz.signing_video)."""
    from aslexp.keypoints import holistic as H
    from aslexp.viz.signing_video import BodyLayout

    names = H.POSE_NAMES
    drawn = tuple(i for i, n in enumerate(names) if i <= names.index("right_hip")) + H.HAND_NODES  # no legs
    hands = {side: tuple(range(offset, offset + H.NUM_HAND))
             for side, offset in (("left", H.LEFT_HAND_OFFSET), ("right", H.RIGHT_HAND_OFFSET))}  # fmt: skip
    arm = ("shoulder", "elbow", "wrist", "pinky", "index", "thumb")
    sides = {side: tuple(names.index(f"{side}_{point}") for point in arm) + hands[side] for side in hands}
    # the face apart from the shoulders, as MediaPipe draws it (aslexp's links from the nose make a tent)
    nose_links = {(names.index("nose"), names.index(f"{side}_shoulder")) for side in hands}
    return BodyLayout(
        edges=tuple((i, j) for i, j in H.EDGES if i in drawn and j in drawn and (i, j) not in nose_links),
        drawn=drawn,
        face=tuple(range(names.index("mouth_right") + 1)), ears=(names.index("left_ear"), names.index("right_ear")),
        shoulders=(names.index("left_shoulder"), names.index("right_shoulder")),
        hips=(names.index("left_hip"), names.index("right_hip")), sides=sides, hands=hands,
        body_hands={side: tuple(names.index(f"{side}_{point}") for point in ("wrist", "pinky", "index", "thumb"))
                    for side in hands},
    )


def _readable_video(source: SigningSource) -> tuple[tuple[Path, int] | None, str]:
    """(the source video, the video frame of the keypoints' first) when it is there as extracted,
    else None and why there is no video panel."""
    video = source.video
    if not video:
        return None, f"{source.image.path}: no video recorded (keypoints not extracted by `aslexp extract VIDEO`)"
    path = Path(video["path"])
    if not path.is_file():
        return None, f"{source.report}: its source video {path} is not there any more"
    if video.get("bytes") is not None and path.stat().st_size != int(video["bytes"]):
        return None, f"{path}: changed since its keypoints were extracted ({video['bytes']} bytes then)"
    return (path, int(video.get("first_frame") or 0)), ""


def write_signing_video(run_dir: str | os.PathLike, source: SigningSource, agent: np.ndarray, times: np.ndarray,
                        label: str, control_hz: float, mp4: bool = True) -> dict:  # fmt: skip
    """``signing.mp4`` (where an encoder exists) and ``signing.gif``: the person (video frame, when
    known; keypoints) beside ``agent`` (T, 75, 4) image keypoints, at the control rate: output frame
    k is the agent's step k, at ``times[k]`` seconds from the episode's start, beside the person's
    frame nearest that time (the source's frames held or skipped)."""
    from aslexp.viz.signing_video import side_by_side
    from aslexp.viz.video import save_gif, save_mp4

    started = time.perf_counter()
    video, why = _readable_video(source)
    if video is None:
        log.info("signing video: no video panel: %s", why)
    source_index = np.round(np.asarray(times, dtype=float) * source.image.fps).astype(int)
    args = (source.image.keypoints, agent, source.camera.width, source.camera.height, source_index, body_layout())
    try:
        try:
            drawn = side_by_side(*args, video=video, agent_label=label)
        except (OSError, RuntimeError, ImportError) as error:  # a video ffmpeg cannot read: the keypoints alone
            if video is None:
                raise
            video, why = None, f"{video[0]}: not readable ({error})"
            log.info("signing video: no video panel: %s", why)
            drawn = side_by_side(*args, video=None, agent_label=label)
    except ValueError as error:  # nothing of either signer to draw (a blown-up agent and no person)
        log.info("signing video: not written: %s", error)
        return {"error": str(error)}
    # the GIF at every second step (as imitation.gif): half the size and the encoding time
    files = [save_gif(drawn.frames[::2], Path(run_dir) / "signing.gif", fps=control_hz / 2).name]
    if mp4 and save_mp4(drawn.frames, Path(run_dir) / SIGNING_VIDEO, control_hz) is not None:
        files.insert(0, SIGNING_VIDEO)
    return {"files": files, "fps": control_hz, "video": str(video[0]) if video else None,
            **({"no_video": why} if video is None else {}), **drawn.describe(),
            "seconds": round(time.perf_counter() - started, 3)}  # fmt: skip


def signing_metrics(env: Any, trajectory: Mapping[str, np.ndarray], run_dir: str | os.PathLike,
                    stage: str = "policy", others: Mapping[str, Mapping[str, np.ndarray]] | None = None,
                    write_pose: bool = True, keypoints: dict[str, np.ndarray] | None = None,
                    video: bool = False, mp4: bool = True) -> dict | None:  # fmt: skip
    """The ``signing`` entry of metrics.json, and ``<run_dir>/signing.pose`` (``trajectory``'s
    simulated body, at the control rate, in the source's image frame); None, with one log line
    saying why, for a motion without source keypoints or a body without the upper body's points.

    Stages: ``reference`` (``trajectory``'s ``q_ref`` played kinematically), ``stage`` (its ``q_sim``)
    and each of ``others`` (name -> trajectory: e.g. the controller alone on the reference).
    ``keypoints``, when given, receives each stage's (T, 75, 4) image keypoints by stage name (a
    read-back reads them: aslexp.signing.reading). ``video``: also ``signing.gif`` and, with ``mp4``,
    ``signing.mp4``, the person beside ``stage`` (:func:`write_signing_video`)."""
    started = time.perf_counter()
    source, why = SigningSource.for_motion(getattr(env.motion, "source", None))
    if source is None:
        log.info("signing: not scored: %s", why)
        return None
    try:
        body_kinematics(env.urdf)
    except ValueError as error:
        log.info("signing: not scored: %s", error)
        return None
    stages: dict[str, dict] = {}
    points: dict[str, np.ndarray] = {}
    stages[REFERENCE_STAGE], points[REFERENCE_STAGE] = score_trajectory(env, trajectory, source, "q_ref")
    stages[stage], points[stage] = score_trajectory(env, trajectory, source, "q_sim")
    for name, other in (others or {}).items():
        stages[name], points[name] = score_trajectory(env, other, source, "q_sim")
    if keypoints is not None:
        keypoints.update(points)
    out: dict = {"source": str(source.image.path), "motion_report": str(source.report),
                 "retargeting_error": source.retargeting_error, "camera": source.camera.to_dict(),
                 "root": "the reference's (a free root's drift is not in the keypoints)", "stages": stages}  # fmt: skip
    if write_pose:
        from aslexp.keypoints.posefile import write_holistic_pose

        path = write_holistic_pose(Path(run_dir) / SIGNING_POSE, points[stage], float(env.spec_env.control_hz),
                                   source.camera.width, source.camera.height)  # fmt: skip
        out["pose_file"] = path.name
    out["seconds"] = round(time.perf_counter() - started, 3)
    if video:  # after the scores' own cost
        hz = float(env.spec_env.control_hz)
        times = np.asarray(trajectory["time"], dtype=float)
        times = times[one_pass(trajectory, float(env.reference.duration), 1.0 / hz)] - (times[0] - 1.0 / hz)
        out["video"] = write_signing_video(run_dir, source, points[stage], times, f"agent ({stage})", hz, mp4)
    return out
