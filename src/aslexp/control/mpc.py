"""Sampling-based model-predictive control: the ceiling of an imitation task (``conf/planner``).

At every control step the planner copies the simulated body's full physics state into ``samples``
rows of a batch (:class:`~aslexp.envs.batched.BatchedImitationEnv`, on an engine that batches),
rolls each row ``horizon`` control steps forward under a candidate sequence of actions, scores each
by the task's own reward summed over the horizon, and applies the first action of the updated plan
(receding horizon). The actions are the environment's residual corrections to its PD controller's
targets (``env.action_mode: residual``; with ``env.residual_velocity_range`` also to its velocity
targets), so the zero sequence is the controller alone: a ceiling starts from the best controller
and can only add to it. Candidates are the current plan (shifted from the last step), the zero
sequence and ``samples - 2`` perturbations of the plan by Gaussian noise (std ``noise`` times each
correction's half-range: ``env.residual_range`` rad, ``env.residual_velocity_range`` rad/s) held over
``knots`` equal pieces of the horizon. The update (``method``):

* ``predictive_sampling`` (MJPC's): the best candidate becomes the plan;
* ``mppi``: the plan is the softmax-weighted mean of the candidates (``temperature`` on the mean
  reward per step over the horizon);
* ``cem``: the plan is the mean of the ``elites`` best, the next iteration's noise their spread.

``iterations`` updates per control step. An update is registered by name (:func:`register_update`,
as a reward error is): a new one is a module plus a YAML whose ``module`` key imports it::

    @register_update("elite_mean")
    def elite_mean(spec, candidates, returns, noise, scale):   # -> (the new plan, the next iteration's noise)
        best = candidates[np.argsort(-returns)[:8]]
        return best.mean(axis=0), noise

    # conf/planner/elite.yaml:  method: elite_mean, module: my_package.my_planners
 The score is measured as every evaluation in aslexp: from
the evaluation protocol's start phases, the mean reward per step over the episode, a blow-up counted
and never scored. The model is the simulator itself (an empirical upper reference, not a bound).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from aslexp.config_schema import Int, Positive, Section, key
from aslexp.envs.assembly import ImitationSetup
from aslexp.errors import ConfigError
from aslexp.plugins import import_modules, register_function
from aslexp.envs.batched import BatchedImitationEnv

log = logging.getLogger("aslexp.mpc")

# name -> update(spec, candidates (S, H, A), returns (S,), noise (A,), scale (A,)) -> (plan (H, A), noise (A,)):
# noise is this iteration's perturbation std, scale each correction's half-range
_UPDATES: dict[str, Callable[..., tuple[np.ndarray, np.ndarray]]] = {}


def register_update(name: str, *, replace: bool = False):
    """Decorator: make ``f(spec, candidates, returns, noise, scale) -> (plan, noise)`` the planner update
    ``name`` (``planner.method``)."""

    return register_function(_UPDATES, "planner update", name, replace)


def unregister_update(name: str) -> None:
    """Forget a registered update (tests register throwaway ones)."""
    _UPDATES.pop(name, None)


def update_names() -> tuple[str, ...]:
    return tuple(_UPDATES)


@register_update("predictive_sampling")
def _best(spec, candidates, returns, noise, scale):
    return candidates[int(np.argmax(returns))].copy(), noise


@register_update("mppi")
def _softmax_mean(spec, candidates, returns, noise, scale):
    weights = np.exp((returns - returns.max()) / (spec.temperature * spec.horizon))
    return np.tensordot(weights / weights.sum(), candidates, axes=1), noise


@register_update("cem")
def _elite_mean(spec, candidates, returns, noise, scale):
    elites = candidates[np.argsort(-returns, kind="stable")[:spec.elites]]
    return elites.mean(axis=0), np.maximum(elites.std(axis=(0, 1)), 1e-3 * spec.noise * scale)




@dataclass(frozen=True)
class PlannerSpec(Section):
    """``conf/planner/*.yaml`` as plain values."""

    SECTION = "planner"

    name: str = "mpc"
    method: str = "predictive_sampling"  # a registered update (register_update)
    horizon: int = field(default=8, metadata=key(Int(1)))  # control steps
    # candidate sequences per iteration (the plan and the zero sequence among them)
    samples: int = field(default=64, metadata=key(Int(3)))
    # std of a perturbation, a fraction of each correction's half-range
    noise: float = field(default=0.025, metadata=key(Positive()))
    # the perturbation is held constant over this many equal pieces of the horizon
    knots: int = field(default=2, metadata=key(Int(1)))
    iterations: int = field(default=1, metadata=key(Int(1)))  # updates per control step
    # mppi: on the mean reward per step over the horizon
    temperature: float = field(default=0.01, metadata=key(Positive()))
    elites: int = field(default=4, metadata=key(Int(1)))  # cem
    seed: int = 0
    # module(s) imported first: they register updates (register_update) method may name
    module: str | list[str] | None = None

    def __post_init__(self) -> None:
        import_modules(self.module)
        if self.method not in _UPDATES:
            raise ConfigError(f"method={self.method}: expected one of {', '.join(update_names())} (a registered "
                              f"update: planner.module names its module)")
        if self.knots > self.horizon:
            raise ConfigError(f"knots={self.knots}: must be at most the horizon ({self.horizon})")
        if self.method == "cem" and self.elites >= self.samples:
            raise ConfigError(f"elites={self.elites}: must be fewer than samples ({self.samples})")


class SamplingPlanner:
    """Plans the residual corrections of one body from any physics state (module docstring)."""

    def __init__(self, spec: PlannerSpec, setup: ImitationSetup) -> None:
        if setup.env.action_mode != "residual":
            raise ValueError(f"planner {spec.name}: plans corrections to the controller's targets and needs "
                             f"env.action_mode residual (env=residual), got {setup.env.action_mode!r}")
        self.spec = spec
        # The candidates' world: no reference state initialisation, no early end, no episode end
        # inside a horizon (a blow-up still ends a row, which then scores nothing more).
        self.batch = BatchedImitationEnv.from_setup(spec.samples, setup.merged(env={
            "reference_state_init": False, "early_termination": {"min_reward": None}, "episode_steps": 10 ** 9}))
        if self.batch.template.spec_env.normalize_actions:
            raise ValueError(f"planner {spec.name}: plans physical corrections; env.normalize_actions must be false")
        box = self.batch.single_action_space
        self.low, self.high = box.low.astype(np.float64), box.high.astype(np.float64)
        self.size = box.shape[0]
        self.scale = (self.high - self.low) / 2  # a perturbation's std is noise x this
        self.rng = np.random.default_rng(spec.seed)
        self.plan = np.zeros((spec.horizon, self.size))
        self._hold = np.arange(spec.horizon) * spec.knots // spec.horizon  # horizon step -> its knot
        self.rollouts = 0  # candidate control steps simulated (the cost)

    def reset(self) -> None:
        """A new episode: the plan is the controller alone."""
        self.plan[:] = 0.0

    def act(self, state: np.ndarray, now: float) -> np.ndarray:
        """The correction to apply now, planned from the physics ``state`` (one row of a batch of the
        same body) at reference time ``now``."""
        spec, noise = self.spec, self.spec.noise * self.scale
        for _ in range(spec.iterations):
            candidates = np.empty((spec.samples, spec.horizon, self.size))
            candidates[0], candidates[1] = self.plan, 0.0
            perturbation = self.rng.normal(size=(spec.samples - 2, spec.knots, self.size)) * noise
            candidates[2:] = self.plan[None] + perturbation[:, self._hold]
            np.clip(candidates, self.low, self.high, out=candidates)
            returns = self._returns(candidates, state, now)
            self.plan, noise = _UPDATES[spec.method](spec, candidates, returns, noise, self.scale)
        action = self.plan[0].copy()
        self.plan = np.concatenate([self.plan[1:], np.zeros((1, self.size))])  # shifted; the end: the controller
        return action

    def _returns(self, candidates: np.ndarray, state: np.ndarray, now: float) -> np.ndarray:
        """The reward of every candidate summed over the horizon, from ``state`` at ``now``."""
        batch = self.batch
        batch.restart_from(state, now)
        total = np.zeros(len(candidates))
        alive = np.ones(len(candidates), dtype=bool)
        for h in range(candidates.shape[1]):
            _, reward, terminated, _, _ = batch.step(candidates[:, h])
            total += np.where(alive, reward, 0.0)
            alive &= ~terminated
        self.rollouts += candidates.shape[0] * candidates.shape[1]
        return total

    def close(self) -> None:
        self.batch.close()


@dataclass
class PlannedEpisode:
    rewards: list[float]
    planned_steps: int
    diverged: bool
    seconds: float
    actions: list[np.ndarray]  # the corrections applied, one per control step
    fell: bool = False  # a free-base body fell (early_termination.fall): ended early, counted, scored 0 after

    @property
    def mean_reward(self) -> float:
        """Sum of step rewards / planned steps: an early end scores 0 for the rest (as evaluations)."""
        return float(np.sum(self.rewards) / max(self.planned_steps, 1))


def plan_episode(planner: SamplingPlanner, body: BatchedImitationEnv, start_time: float, steps: int,
                 progress: str = "") -> PlannedEpisode:
    """One episode of ``body`` (a batch of one: the system the planner drives) from ``start_time``."""
    planner.reset()
    body.reset(options={"time": start_time})
    rewards, actions, started, diverged, fell = [], [], time.perf_counter(), False, False
    for step in range(steps):
        action = planner.act(body.states[0], float(body.time[0]))
        actions.append(action)
        _, reward, terminated, _, info = body.step(action[None])
        if terminated[0] and bool(info.get("fall", [False])[0]):  # a fall ends it as an evaluation's does
            rewards.append(float(reward[0]))
            fell = True
            break
        if terminated[0]:  # no other early end in an evaluation: only a blow-up (or a NaN) ends it
            diverged = True
            break
        rewards.append(float(reward[0]))
        if progress and (step + 1) % max(steps // 4, 1) == 0:
            spent = time.perf_counter() - started
            log.info("%s: %d/%d control steps, mean reward %.4f, %.3f s per step, ETA %.0f s", progress, step + 1,
                     steps, np.mean(rewards), spent / (step + 1), spent / (step + 1) * (steps - step - 1))
    return PlannedEpisode(rewards, steps, diverged, time.perf_counter() - started, actions, fell)


def evaluate_planner(spec: PlannerSpec, setup: ImitationSetup, phases: tuple[float, ...], steps: int,
                     label: str = "") -> dict[str, Any]:
    """The planner's score under the evaluation protocol: from each start phase, ``steps`` control
    steps, the mean reward per step averaged over the phases; its cost in seconds per control step."""
    scored = setup.merged(env={"reference_state_init": False, "early_termination": {"min_reward": None},
                               "episode_steps": max(steps, 1)})
    planner = SamplingPlanner(spec, setup)
    body = BatchedImitationEnv.from_setup(1, scored)
    try:
        episodes = [plan_episode(planner, body, phase * body.reference.duration, steps,
                                 progress=f"{label or 'planner'} phase {phase:g}") for phase in phases]
    finally:
        planner.close()
        body.close()
    seconds = sum(e.seconds for e in episodes)
    control_steps = sum(len(e.rewards) for e in episodes)
    return {"reward": float(np.mean([e.mean_reward for e in episodes])),
            "per_phase": [e.mean_reward for e in episodes], "phases": list(phases), "steps": steps,
            "diverged": sum(e.diverged for e in episodes), "fell": sum(e.fell for e in episodes),
            "seconds": round(seconds, 2),
            "seconds_per_step": round(seconds / max(control_steps, 1), 5),
            "rollout_steps_per_step": planner.rollouts // max(control_steps, 1)}
