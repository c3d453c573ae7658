"""Driving a body with the reference and no policy: the PD-tuning objective (thesis 5.3.1) and the
no-learning baselines every learned result is reported beside."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from aslexp.envs.imitation import ImitationEnv

# reward: 1 - the imitation reward (default); mean_abs: aslexp's earlier unweighted errors; thesis: Eq. 5.14
OBJECTIVES = ("reward", "mean_abs", "thesis")


@dataclass
class Rollout:
    """One reference-driven episode from a start time."""

    rewards: list[float] = field(default_factory=list)
    planned_steps: int = 0
    ended_early: bool = False
    fell: bool = False
    diverged: bool = False
    terms: dict[str, float] = field(default_factory=dict)  # mean per-term rewards over the steps run
    score_sums: dict[str, float] = field(default_factory=dict)  # the env's score_rewards, summed over the steps
    pose_errors: list[np.ndarray] = field(default_factory=list)  # per step, per joint (see record)
    velocity_errors: list[np.ndarray] = field(default_factory=list)

    @property
    def mean_reward(self) -> float:
        """Sum of step rewards / planned steps: an early end scores 0 for the rest (as evaluations)."""
        return float(np.sum(self.rewards) / max(self.planned_steps, 1))

    @property
    def scores(self) -> dict[str, float]:
        """The env's ``score_rewards`` as :attr:`mean_reward` (per planned step)."""
        return {k: v / max(self.planned_steps, 1) for k, v in self.score_sums.items()}


def reference_rollout(env: ImitationEnv, steps: int, lookahead: int = 1, start_time: float = 0.0,
                      record_errors: bool = False) -> Rollout:
    """Step ``env`` with its reference ``lookahead`` control steps ahead (``env.reference_action``:
    a zero correction in residual mode) for ``steps`` control steps from ``start_time``. With
    ``record_errors`` each step's per-joint pose errors (rad: the angle of the quaternion difference
    for a spherical joint) and velocity errors are kept (the reward's own error definitions)."""
    env.reset(options={"time": start_time})
    out = Rollout(planned_steps=steps)
    sums: dict[str, float] = {}
    for _ in range(steps):
        _, reward, terminated, _, info = env.step(env.reference_action(lookahead))
        if info.get("diverged"):
            out.diverged = out.ended_early = True
            break
        out.rewards.append(float(reward))
        for name, value in info.items():
            if name.startswith("r_"):
                sums[name[2:]] = sums.get(name[2:], 0.0) + value
            elif name.startswith("score_"):
                out.score_sums[name[6:]] = out.score_sums.get(name[6:], 0.0) + value
        if record_errors:
            pose_sq, vel_sq = env.reward_fn.joint_errors(env.last_sim_state, env.last_reference_state)
            out.pose_errors.append(np.sqrt(pose_sq))
            out.velocity_errors.append(np.sqrt(vel_sq))
        if terminated:
            out.ended_early, out.fell = True, bool(info.get("fall"))
            break
    out.terms = {k: v / max(len(out.rewards), 1) for k, v in sums.items()}
    return out


def pd_tracking_error(env: ImitationEnv, steps: int | None = None, lookahead: int = 1,
                      objective: str = "reward") -> dict[str, Any]:
    """Drive the PD targets with the reference ``lookahead`` control steps ahead, from time 0.

    ``objective`` (minimised): ``reward`` (the default): 1 - the mean imitation reward, the env's
    own reward config (its terms, weights and scales), so the best gains are the best-scoring ones;
    ``mean_abs``: mean over steps and joints of |position error| (rad) plus the same of |velocity
    error| (rad/s), unweighted; ``thesis`` (Eq. 5.14): e_p + e_v with each the Eq. 5.10 sum over
    joints of squared errors, averaged over the steps. Returns both error parts (mean |error| for
    ``reward``), the objective, the mean imitation reward and whether the simulation diverged.
    """
    if objective not in OBJECTIVES:
        raise ValueError(f"tune_pd: tuning.objective must be one of {OBJECTIVES}, got {objective!r}")
    steps = steps or max(1, int(env.reference.duration / env.control_dt))
    run = reference_rollout(env, steps, lookahead, record_errors=True)
    if run.diverged or not run.pose_errors:
        return {"pose_error": float("inf"), "velocity_error": float("inf"), "objective": float("inf"),
                "objective_kind": objective, "reward": 0.0, "diverged": True, "steps": len(run.pose_errors)}
    pose, vel = np.asarray(run.pose_errors), np.asarray(run.velocity_errors)
    if objective == "thesis":
        pose_err, vel_err = float(np.mean(np.sum(pose ** 2, axis=1))), float(np.mean(np.sum(vel ** 2, axis=1)))
    else:
        pose_err, vel_err = float(np.mean(pose)), float(np.mean(vel))
    reward = run.mean_reward  # per planned step: an early end scores 0 for the rest, as evaluations
    value = 1.0 - reward if objective == "reward" else pose_err + vel_err
    return {"pose_error": pose_err, "velocity_error": vel_err, "objective": value,
            "objective_kind": objective, "reward": reward, "diverged": False, "steps": len(run.pose_errors)}
