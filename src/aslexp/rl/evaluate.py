"""Deterministic evaluation of a policy (or of the reference-driven baselines) on an imitation env.

An evaluation is several deterministic episodes that start at different phases of the motion
(:func:`evaluate_phases`; PPO's ``eval_episodes`` / ``eval_phases``), so that one lucky start
state does not make the number; the baselines are measured under the same protocol.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np


class EvaluatedEnv(Protocol):
    """What evaluation takes of an environment: any env with the interface of
    :class:`aslexp.envs.imitation.ImitationEnv` (rl imports no environment; duck typing).

    :func:`evaluate` uses these; the baseline policies also call the env's reference and action
    helpers (``reference_action``, ``reference_targets``, ``residual_base``, ``normalize_action``, ...).
    """

    spec_env: Any  # the env's EnvSpec: episode_steps, action_mode, ...
    sim: Any  # joint_state()
    reference: Any  # joints(t), joint_velocities(t)
    time: float
    render_mode: str | None
    action_space: Any

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]: ...

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]: ...

    def render(self) -> Any: ...


Policy = Callable[[np.ndarray, "EvaluatedEnv"], np.ndarray]


@dataclass
class Evaluation:
    """Result of one deterministic episode."""

    mean_reward: float  # sum of step rewards / planned steps (an early end scores 0 for the rest)
    steps: int
    terms: dict[str, float]
    ended_early: bool
    trajectory: dict[str, np.ndarray] = field(default_factory=dict)
    diverged: bool = False  # ended because the simulation blew up (a NaN action counts too): an error, not a score
    scores: dict[str, float] = field(default_factory=dict)  # the env's score_rewards, as mean_reward
    divergence: dict[str, Any] | None = None  # where it blew up (the env's info["divergence"])
    phase: float = 0.0  # of the motion at the start
    # RMS of the actions over steps and values, each as (action - box centre) / box half-width: 0 is
    # the centre (for a residual action: no correction, the controller), 1 the box's edge. In the
    # units of the policy's exploration std (exp(log_std)), so the two compare directly.
    action_rms: float = float("nan")


@dataclass
class EvaluationSummary:
    """Deterministic episodes from several start phases: the mean is the evaluation's reward."""

    mean_reward: float  # mean over the episodes
    std: float  # over the episodes (population std)
    rewards: list[float]  # per episode, in the order of ``phases``
    phases: tuple[float, ...]
    terms: dict[str, float]  # per-term means over the episodes
    ended_early: int  # episodes that ended before their planned steps
    action_rms: float = float("nan")  # over every step of every episode (see Evaluation)
    diverged: int = 0  # episodes whose simulation blew up (or got a NaN action): their numbers are not scores
    scores: dict[str, float] = field(default_factory=dict)  # the env's score_rewards, means over the episodes
    divergences: list[dict[str, Any]] = field(default_factory=list)  # per episode that blew up: phase, where


def even_phases(count: int) -> tuple[float, ...]:
    """``count`` start phases spread evenly over the motion: 0, 1/count, 2/count, ..."""
    if count < 1:
        raise ValueError(f"evaluation needs at least one episode, got {count}")
    return tuple(k / count for k in range(count))


def evaluate(env: EvaluatedEnv, policy: Policy, steps: int | None = None, record: bool = False,
             frames_every: int = 0, phase: float = 0.0) -> Evaluation:
    """Run ``policy(obs, env) -> action`` for ``steps`` control steps from ``phase`` of the motion
    (0: its start), deterministically.

    With ``record`` the trajectory holds time, simulated and reference joint positions and
    velocities (for the figures); with ``frames_every`` > 0 also rendered frames.
    """
    steps = steps or env.spec_env.episode_steps
    obs, _ = env.reset(options={"phase": float(phase)})
    rewards, term_sums, score_sums = [], {}, {}
    traj: dict[str, list] = {"time": [], "q_sim": [], "q_ref": [], "qd_sim": [], "qd_ref": [], "reward": [],
                             "frames": []}
    ended_early = diverged = False
    divergence = None
    centre, half = _action_box(env)
    squares = 0.0
    for k in range(steps):
        action = policy(obs, env)
        if centre is not None:
            squares += float(np.mean(((np.asarray(action, dtype=np.float64).reshape(-1) - centre) / half) ** 2))
        obs, reward, terminated, truncated, info = env.step(action)
        rewards.append(reward)
        for name, value in info.items():
            if name.startswith("r_"):
                term_sums[name[2:]] = term_sums.get(name[2:], 0.0) + value
            elif name.startswith("score_"):
                score_sums[name[6:]] = score_sums.get(name[6:], 0.0) + value
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
            diverged = bool(info.get("diverged") or info.get("nan_action"))
            divergence = info.get("divergence") or ({"nan_action": True} if info.get("nan_action") else None)
            break
    n = max(len(rewards), 1)
    trajectory = {k: np.asarray(v) for k, v in traj.items() if len(v)} if record else {}
    return Evaluation(
        mean_reward=float(np.sum(rewards) / steps), steps=len(rewards),
        terms={k: v / n for k, v in term_sums.items()}, ended_early=ended_early, trajectory=trajectory,
        phase=float(phase), action_rms=math.sqrt(squares / n) if centre is not None else float("nan"),
        diverged=diverged, scores={k: v / steps for k, v in score_sums.items()},
        divergence=divergence if diverged else None,
    )


def _action_box(env) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Centre and half-width of a bounded Box action space (None, None otherwise)."""
    space = getattr(env, "action_space", None)
    low, high = getattr(space, "low", None), getattr(space, "high", None)
    if low is None or not (np.all(np.isfinite(low)) and np.all(np.isfinite(high)) and np.all(high > low)):
        return None, None
    low, high = np.asarray(low, dtype=np.float64), np.asarray(high, dtype=np.float64)
    return (low + high) / 2, (high - low) / 2


def evaluate_phases(env: EvaluatedEnv, policy: Policy, steps: int | None = None,
                    phases: tuple[float, ...] = (0.0,)) -> EvaluationSummary:
    """One deterministic episode of ``steps`` control steps from each start phase; their mean."""
    if not phases:
        raise ValueError("evaluation needs at least one start phase")
    episodes = [evaluate(env, policy, steps, phase=phase) for phase in phases]
    rewards = [e.mean_reward for e in episodes]
    names = dict.fromkeys(k for e in episodes for k in e.terms)
    return EvaluationSummary(
        mean_reward=float(np.mean(rewards)), std=float(np.std(rewards)), rewards=rewards,
        phases=tuple(float(p) for p in phases),
        terms={k: float(np.mean([e.terms[k] for e in episodes if k in e.terms])) for k in names},
        ended_early=sum(e.ended_early for e in episodes), diverged=sum(e.diverged for e in episodes),
        scores={k: float(np.mean([e.scores.get(k, 0.0) for e in episodes])) for k in episodes[0].scores},
        divergences=[{"phase": e.phase, **(e.divergence or {})} for e in episodes if e.diverged],
        action_rms=math.sqrt(sum(e.action_rms ** 2 * e.steps for e in episodes)
                             / max(sum(e.steps for e in episodes), 1)),
    )


def evaluate_rows(env, act: Callable[[np.ndarray], np.ndarray], steps: int, clips: np.ndarray,
                  phases: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`evaluate`'s deterministic episodes, all at once on a batch of many motions (an env with
    :class:`aslexp.envs.batched.BatchedImitationEnv`'s interface, one row per episode): row ``i``
    imitates pool motion ``clips[i]`` from ``phases[i]``. ``act(obs)``: the batch's actions. Returns
    each row's mean reward (an early end scores 0 for the rest, as :func:`evaluate`'s) and whether it
    blew up (its simulation diverged or its action was not finite: an error, never a score)."""
    obs, _ = env.reset(options={"clip": np.asarray(clips), "phase": np.asarray(phases, dtype=np.float64)})
    n = env.num_envs
    total, running, blew_up = np.zeros(n), np.ones(n, dtype=bool), np.zeros(n, dtype=bool)
    for _ in range(steps):
        action = np.asarray(act(obs), dtype=np.float64).reshape(n, -1)
        blew_up |= running & ~np.isfinite(action).all(axis=1)
        obs, reward, terminated, _, info = env.step(action)
        total += np.where(running, reward, 0.0)
        blew_up |= running & np.asarray(info.get("diverged", np.zeros(n, dtype=bool)))
        running &= ~np.asarray(terminated)  # the row's next episode (same-step autoreset) is not scored
        if not running.any():
            break
    return total / steps, blew_up


def reference_policy(lookahead: int) -> Policy:
    """The no-learning baseline: PD targets = the reference ``lookahead`` control steps ahead."""
    return lambda obs, env: env.reference_action(lookahead)


def smoothed_reference_policy(alpha: float, groups: tuple[str, ...] | None = None) -> Policy:
    """A no-learning baseline for a residual action: the reference one step ahead, low-pass
    filtered, ``target_t = alpha * target_(t-1) + (1 - alpha) * reference_(t+1)`` on the joints of
    ``groups`` (all joints when None; quaternion targets are renormalised by the controller).

    Gentler targets mean smaller reaction torques: on the standing upper body this alone stops
    much of the feet's slip (the yaw drift that costs the authors' stable PD its reward), so it is
    the simple baseline a learned correction has to be compared with, not only the bare controller.
    The filter restarts with every episode (``env.steps == 0``).
    """
    if not 0.0 <= alpha < 1.0:
        raise ValueError(f"smoothing alpha must be in [0, 1), got {alpha}")
    state: dict[str, np.ndarray | None] = {"previous": None, "index": None}

    def policy(obs: np.ndarray, env: EvaluatedEnv) -> np.ndarray:
        if state["index"] is None:
            state["index"] = env.joint_value_indices(groups, "smoothing")
        base = env.residual_base() if env.spec_env.action_mode == "residual" else None
        ahead = env.reference_targets(1)
        if env.steps == 0 or state["previous"] is None:
            state["previous"] = ahead.copy()
        target = ahead.copy()
        index = state["index"]
        target[index] = alpha * state["previous"][index] + (1.0 - alpha) * ahead[index]
        state["previous"] = target
        action = target - base if base is not None else target
        if env.spec_env.residual_velocity_range > 0:  # no velocity-target correction
            action = np.concatenate([action, np.zeros(env.velocity_size)])
        # Within the action box, as a policy's would be (a residual's +-residual_range).
        action = np.clip(env.policy_part(action), env.physical_action_space.low, env.physical_action_space.high)
        return env.normalize_action(action).astype(np.float32)

    return policy


def constant_correction_policy(rms: float, seed: int) -> Policy:
    """A no-learning control for a residual policy: the controller plus one fixed random correction,
    a Gaussian vector rescaled to RMS ``rms`` in half-widths of the action box (the units of
    ``Evaluation.action_rms``), drawn once from ``seed`` and held for every step of every episode.

    A family of these at the size a learned correction has measures how far a correction that
    learned nothing moves the evaluation: on a body whose feet slip, tiny target changes decide
    whether they slip, and a learned gain smaller than this spread is not told apart from chance.
    """
    if rms < 0:
        raise ValueError(f"a correction's RMS must be >= 0, got {rms}")
    state: dict[str, np.ndarray] = {}

    def policy(obs: np.ndarray, env: EvaluatedEnv) -> np.ndarray:
        if env.spec_env.action_mode != "residual":
            raise ValueError("constant random corrections need a residual action (env.action_mode=residual)")
        if "action" not in state:
            centre, half = _action_box(env)
            draw = np.random.default_rng(seed).standard_normal(centre.shape)
            state["action"] = (centre + half * draw * (rms / math.sqrt(float(np.mean(draw ** 2))))).astype(np.float32)
        return state["action"]

    return policy


def baselines(env: EvaluatedEnv, steps: int | None = None, phases: tuple[float, ...] = (0.0,)) -> dict[str, float]:
    """Mean reward of the reference-tracking baselines, each evaluated as a policy is: one
    deterministic episode from each of ``phases``, averaged (pass the PPO config's phases).

    ``reference`` and ``lookahead``: the reference now / one control step ahead as held PD
    targets with zero velocity targets. When the env's controller has target options on
    (reference velocity targets, physics-rate reference) they are measured with the env's
    default controller (``env.thesis_pd()``: thesis gains and targets), and
    ``reference_velocity_pd`` is the env's own controller with no policy correction: a stronger
    no-learning baseline, reported beside the others, not instead of them.
    """
    whole_body = getattr(env, "whole_body", None)  # env.policy_groups: the baselines drive every joint
    with whole_body() if whole_body is not None else contextlib.nullcontext(env) as env:
        thesis_pd = getattr(env, "thesis_pd", contextlib.nullcontext)
        with thesis_pd():
            out = {
                "reference": evaluate_phases(env, reference_policy(0), steps, phases).mean_reward,
                "lookahead": evaluate_phases(env, reference_policy(1), steps, phases).mean_reward,
            }
        controller = getattr(env, "controller_spec", None)
        if controller is not None and not controller.is_thesis_pd:
            lookahead = env.spec_env.reference_lookahead  # a zero correction in residual mode
            out["reference_velocity_pd"] = evaluate_phases(env, reference_policy(lookahead), steps,
                                                           phases).mean_reward
    return out

