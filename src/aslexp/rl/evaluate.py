"""Deterministic evaluation of a policy (or of the reference-driven baselines) on an imitation env."""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # rl takes any env with the ImitationEnv interface; no import at run time
    from aslexp.envs.imitation import ImitationEnv


@dataclass
class Evaluation:
    """Result of one deterministic episode from phase 0."""

    mean_reward: float  # sum of step rewards / planned steps (an early end scores 0 for the rest)
    steps: int
    terms: dict[str, float]
    ended_early: bool
    trajectory: dict[str, np.ndarray] = field(default_factory=dict)


def evaluate(env: ImitationEnv, policy: Callable[[np.ndarray, ImitationEnv], np.ndarray],
             steps: int | None = None, record: bool = False, frames_every: int = 0) -> Evaluation:
    """Run ``policy(obs, env) -> action`` for ``steps`` control steps from time 0, deterministically.

    With ``record`` the trajectory holds time, simulated and reference joint positions and
    velocities (for the figures); with ``frames_every`` > 0 also rendered frames.
    """
    steps = steps or env.spec_env.episode_steps
    obs, _ = env.reset(options={"time": 0.0})
    rewards, term_sums = [], {}
    traj: dict[str, list] = {"time": [], "q_sim": [], "q_ref": [], "qd_sim": [], "qd_ref": [], "reward": [],
                             "frames": []}
    ended_early = False
    for k in range(steps):
        obs, reward, terminated, truncated, info = env.step(policy(obs, env))
        rewards.append(reward)
        for name, value in info.items():
            if name.startswith("r_"):
                term_sums[name[2:]] = term_sums.get(name[2:], 0.0) + value
        if record:
            q, qd = env.sim.joint_state()
            traj["time"].append(env.time)
            traj["q_sim"].append(q)
            traj["qd_sim"].append(qd)
            traj["q_ref"].append(env.reference.joints(env.time))
            traj["qd_ref"].append(env.reference.joint_velocities(env.time))
            traj["reward"].append(reward)
            if frames_every and k % frames_every == 0 and env.render_mode == "rgb_array":
                traj["frames"].append(env.render())
        if terminated:
            ended_early = True
            break
    n = max(len(rewards), 1)
    trajectory = {k: np.asarray(v) for k, v in traj.items() if len(v)} if record else {}
    return Evaluation(
        mean_reward=float(np.sum(rewards) / steps), steps=len(rewards),
        terms={k: v / n for k, v in term_sums.items()}, ended_early=ended_early, trajectory=trajectory,
    )


def reference_policy(lookahead: int) -> Callable[[np.ndarray, ImitationEnv], np.ndarray]:
    """The no-learning baseline: PD targets = the reference ``lookahead`` control steps ahead."""
    return lambda obs, env: env.reference_action(lookahead)


def baselines(env: ImitationEnv, steps: int | None = None) -> dict[str, float]:
    """Mean reward of the reference-tracking baselines.

    ``reference`` and ``lookahead``: the reference now / one control step ahead as held PD
    targets with zero velocity targets. When the env's controller has target options on
    (reference velocity targets, physics-rate reference) they are measured with the env's
    default controller (``env.thesis_pd()``: thesis gains and targets), and
    ``reference_velocity_pd`` is the env's own controller with no policy correction: a stronger
    no-learning baseline, reported beside the others, not instead of them.
    """
    thesis_pd = getattr(env, "thesis_pd", contextlib.nullcontext)
    with thesis_pd():
        out = {
            "reference": evaluate(env, reference_policy(0), steps).mean_reward,
            "lookahead": evaluate(env, reference_policy(1), steps).mean_reward,
        }
    controller = getattr(env, "controller_spec", None)
    if controller is not None and not controller.is_thesis_pd:
        lookahead = env.spec_env.reference_lookahead  # a zero correction in residual mode
        out["reference_velocity_pd"] = evaluate(env, reference_policy(lookahead), steps).mean_reward
    return out
