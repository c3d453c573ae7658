"""How well a PD controller alone tracks a reference: the PD-tuning objective (thesis 5.3.1)."""

from __future__ import annotations

from typing import Any

import numpy as np

from aslexp.envs.imitation import ImitationEnv


def pd_tracking_error(env: ImitationEnv, steps: int | None = None, lookahead: int = 1) -> dict[str, Any]:
    """Drive the PD targets with the reference ``lookahead`` control steps ahead, from time 0.

    Returns the mean absolute joint position error (rad), velocity error (rad/s), their sum
    (the objective), the mean imitation reward and whether the simulation diverged.
    """
    steps = steps or max(1, int(env.reference.duration / env.control_dt))
    env.reset(options={"time": 0.0})
    pose_err, vel_err, rewards = [], [], []
    diverged = False
    for _ in range(steps):
        _, reward, terminated, _, info = env.step(env.reference_action(lookahead))
        if info.get("diverged"):
            diverged = True
            break
        q, qd = env.sim.joint_state()
        pose_err.append(np.mean(np.abs(q - env.reference.joints(env.time))))
        vel_err.append(np.mean(np.abs(qd - env.reference.joint_velocities(env.time))))
        rewards.append(reward)
        if terminated:
            break
    if diverged or not pose_err:
        return {"pose_error": float("inf"), "velocity_error": float("inf"), "objective": float("inf"),
                "reward": 0.0, "diverged": True, "steps": len(pose_err)}
    pose, vel = float(np.mean(pose_err)), float(np.mean(vel_err))
    return {"pose_error": pose, "velocity_error": vel, "objective": pose + vel,
            "reward": float(np.mean(rewards)), "diverged": False, "steps": len(pose_err)}
