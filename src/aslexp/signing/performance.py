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


def signing_metrics(env: Any, trajectory: Mapping[str, np.ndarray], run_dir: str | os.PathLike,
                    stage: str = "policy", others: Mapping[str, Mapping[str, np.ndarray]] | None = None,
                    write_pose: bool = True, keypoints: dict[str, np.ndarray] | None = None) -> dict | None:  # fmt: skip
    """The ``signing`` entry of metrics.json, and ``<run_dir>/signing.pose`` (``trajectory``'s
    simulated body, at the control rate, in the source's image frame); None, with one log line
    saying why, for a motion without source keypoints or a body without the upper body's points.

    Stages: ``reference`` (``trajectory``'s ``q_ref`` played kinematically), ``stage`` (its ``q_sim``)
    and each of ``others`` (name -> trajectory: e.g. the controller alone on the reference).
    ``keypoints``, when given, receives each stage's (T, 75, 4) image keypoints by stage name (a
    read-back reads them: aslexp.signing.reading)."""
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
    return out
