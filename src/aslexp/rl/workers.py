"""Rollout workers: each environment steps in its own process WITH a copy of the policy.

``vector_env: workers`` (:class:`PolicyWorkers`). Lockstep vector environments
(:mod:`aslexp.rl.vector`, ``async``) send one action to every worker and wait for every observation
at each step, with the policy batched in the learner: one inter-process round trip per step. For a
physics simulator whose step takes a millisecond or two, that round trip (and the learner's
inference, which the workers wait for) is the cost: on 2 cores, two lockstep workers collected
0.93x as fast as one environment in the learner's process (hand, 30 Hz, 2026-11-23,
``bench/ppo_scaling.py``). Here each worker gets the policy's weights once per rollout, steps its
environment ``steps`` times with a one-thread CPU copy of the actor (sampling from its own seeded
noise, white or coloured: :mod:`aslexp.rl.noise`), and sends back the whole segment: one round trip
per rollout. What the learner needs comes back unchanged: raw observations (the observation
normaliser's statistics are updated by the learner from all workers' observations, so they are
merged exactly), actions, rewards, terminations and the final observation of every episode
(same-step autoreset, as the vector environments).

Determinism: worker ``i`` resets with the seed :func:`~aslexp.rl.vector.worker_seeds` gives it
and samples its action noise from ``noise_seeds(seed, i, start_step)``; the same seeds give
the same transitions, whatever the number of cores (:func:`rollout_segment` is the worker's
whole loop, and runs in this process too, for one environment or a test).
"""

from __future__ import annotations

import traceback
from collections.abc import Callable
from typing import Any

import gymnasium as gym
import numpy as np
import torch

from aslexp.rl.noise import ActionNoise
from aslexp.rl.policy import Agent
from aslexp.rl.vector import DropInfo, worker_context

# The agent's entries the workers need (the critic stays with the learner).
ACTOR_PREFIXES = ("normalizer.", "actor.", "action_center", "action_half_range")


def noise_seeds(seed: int, num_envs: int, start_step: int = 0) -> list[int]:
    """Seeds of the workers' action-noise generators (distinct from their reset seeds)."""
    return [int(np.random.SeedSequence([seed, worker, start_step, 1]).generate_state(1)[0])
            for worker in range(num_envs)]


def actor_state(agent: Agent) -> dict[str, np.ndarray]:
    """The weights a worker's policy copy needs, as numpy arrays (cheap to pickle)."""
    return {k: v.detach().cpu().numpy() for k, v in agent.state_dict().items() if k.startswith(ACTOR_PREFIXES)}


def rollout_segment(env: gym.Env, agent: Agent, noise: ActionNoise, obs: np.ndarray,
                    steps: int) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """``steps`` steps of one environment under the agent's stochastic policy, from ``obs``.

    Returns the segment (raw ``obs`` and ``next_obs`` -- the final observation where an episode
    ended --, normalised ``action``, ``reward``, ``terminated``, ``truncated``) and the observation
    to continue from (a new episode's first where the last step ended one)."""
    obs_size, act_size = obs.shape[0], agent.action_center.shape[0]
    out = {"obs": np.empty((steps, obs_size), np.float32), "next_obs": np.empty((steps, obs_size), np.float32),
           "action": np.empty((steps, act_size), np.float32), "reward": np.empty(steps, np.float32),
           "terminated": np.empty(steps, bool), "truncated": np.empty(steps, bool)}
    with torch.no_grad():
        for t in range(steps):
            out["obs"][t] = obs
            loc, scale = agent.head(agent.normalizer(torch.from_numpy(out["obs"][t:t + 1])))
            a = loc + scale * noise.sample()
            out["action"][t] = a[0].numpy()
            next_obs, reward, terminated, truncated, _ = env.step(agent.to_env_action(a)[0].numpy())
            out["next_obs"][t] = next_obs
            out["reward"][t], out["terminated"][t], out["truncated"][t] = reward, terminated, truncated
            if terminated or truncated:  # same-step autoreset, as gymnasium's vector environments
                next_obs, _ = env.reset()
                noise.restart()
            obs = np.asarray(next_obs, np.float32)
    return out, obs


def rollout_batch_segment(envs, agent: Agent, noises: list[ActionNoise], obs: np.ndarray,
                          steps: int) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """:func:`rollout_segment` for a batched vector environment of ``k`` environments (one noise
    generator each): arrays shaped ``(steps, k, ...)``, the policy batched over the k."""
    k, obs_size, act_size = len(noises), obs.shape[1], agent.action_center.shape[0]
    out = {"obs": np.empty((steps, k, obs_size), np.float32), "next_obs": np.empty((steps, k, obs_size), np.float32),
           "action": np.empty((steps, k, act_size), np.float32), "reward": np.empty((steps, k), np.float32),
           "terminated": np.empty((steps, k), bool), "truncated": np.empty((steps, k), bool)}
    with torch.no_grad():
        for t in range(steps):
            out["obs"][t] = obs
            loc, scale = agent.head(agent.normalizer(torch.from_numpy(out["obs"][t])))
            a = loc + scale * torch.stack([noise.sample() for noise in noises])
            out["action"][t] = a.numpy()
            next_obs, reward, terminated, truncated, info = envs.step(agent.to_env_action(a).numpy())
            out["next_obs"][t] = next_obs
            for i in np.flatnonzero(terminated | truncated):  # same-step autoreset
                out["next_obs"][t, i] = info["final_obs"][i]
                noises[i].restart()
            out["reward"][t], out["terminated"][t], out["truncated"][t] = reward, terminated, truncated
            obs = np.asarray(next_obs, np.float32)
    return out, obs


def _serve(pipe, make_env: Callable[..., gym.Env], make_agent: Callable[[gym.Space, gym.Space], Agent],
           envs_per_worker: int = 0) -> None:
    """A worker's loop: commands from the learner until ``close``. With ``envs_per_worker`` > 0 the
    worker's environment is ``make_env(envs_per_worker)``, a batched vector environment."""
    torch.set_num_threads(1)
    env = agent = noise = obs = None
    while True:
        command, data = pipe.recv()
        try:
            if command == "close":
                if env is not None:
                    env.close()
                pipe.send(("ok", None))
                return
            if env is None:
                env = make_env(envs_per_worker) if envs_per_worker else DropInfo(make_env())
                spaces = ((env.single_observation_space, env.single_action_space) if envs_per_worker
                          else (env.observation_space, env.action_space))
                agent = make_agent(*spaces)
            if command == "spaces":
                result = spaces
            elif command == "reset":
                reset_seed, noise_seed, beta, horizon = data
                obs, _ = env.reset(seed=reset_seed)
                obs = np.asarray(obs, np.float32)
                size = spaces[1].shape[0]
                noise = ([ActionNoise(size, s, beta, horizon) for s in noise_seed] if envs_per_worker
                         else ActionNoise(size, noise_seed, beta, horizon))
                result = None
            elif command == "rollout":
                weights, steps = data
                agent.load_state_dict({k: torch.from_numpy(v) for k, v in weights.items()}, strict=False)
                rollout = rollout_batch_segment if envs_per_worker else rollout_segment
                result, obs = rollout(env, agent, noise, obs, steps)
            elif command == "call":
                result = env.call(data)[0] if envs_per_worker else getattr(env, data)()
            else:
                raise ValueError(f"unknown command {command!r}")
            pipe.send(("ok", result))
        except Exception:  # noqa: BLE001 - the learner raises it, with this worker's traceback
            pipe.send(("error", traceback.format_exc()))


class WorkerError(RuntimeError):
    """A rollout worker failed; the message carries its traceback."""


class PolicyWorkers:
    """``num_envs`` worker processes, each an environment and a copy of the policy; or, with
    ``envs_per_worker`` > 0, ``num_envs / envs_per_worker`` processes each stepping a batch of
    ``envs_per_worker`` environments (``make_env(k)``: :class:`~aslexp.envs.batched.BatchedImitationEnv`)
    with its policy copy batched over them: many cores, each stepping its batch.

    ``make_env`` must be picklable (e.g. ``functools.partial(ImitationEnv, ...)``), as must
    ``make_agent`` (observation space, action space -> an :class:`Agent` of the learner's
    architecture, e.g. ``functools.partial(agent_for_spaces, config.model)``)."""

    def __init__(self, make_env: Callable[..., gym.Env], num_envs: int,
                 make_agent: Callable[[gym.Space, gym.Space], Agent], envs_per_worker: int = 0) -> None:
        context = worker_context(make_env)
        if envs_per_worker and num_envs % envs_per_worker:
            raise ValueError(f"ppo config: num_envs ({num_envs}) must be a multiple of the environments per "
                             f"worker ({envs_per_worker})")
        self.num_envs = num_envs
        self.envs_per_worker = envs_per_worker
        self.num_workers = num_envs // envs_per_worker if envs_per_worker else num_envs
        self._pipes, self._processes = [], []
        for index in range(self.num_workers):
            parent, child = context.Pipe()
            process = context.Process(target=_serve, args=(child, make_env, make_agent, envs_per_worker),
                                      name=f"aslexp-rollout-{index}", daemon=True)
            process.start()
            child.close()
            self._pipes.append(parent)
            self._processes.append(process)
        self._closed = False
        self.single_observation_space, self.single_action_space = self._ask_one(0, "spaces", None)

    def _ask_one(self, index: int, command: str, data: Any) -> Any:
        self._pipes[index].send((command, data))
        return self._answer(index)

    def _answer(self, index: int) -> Any:
        try:
            status, result = self._pipes[index].recv()
        except EOFError as exc:
            raise WorkerError(f"rollout worker {index} died (exit code {self._processes[index].exitcode})") from exc
        if status == "error":
            raise WorkerError(f"rollout worker {index} failed:\n{result}")
        return result

    def _ask_all(self, command: str, per_worker: list[Any]) -> list[Any]:
        for pipe, data in zip(self._pipes, per_worker):  # all start before any answer is awaited
            pipe.send((command, data))
        return [self._answer(i) for i in range(self.num_workers)]

    def reset(self, reset_seeds: list[int], noise_seeds_: list[int], noise_beta: float = 0.0,
              noise_horizon: int = 300) -> None:
        """New episodes from these seeds (one per environment); action noise of colour
        ``noise_beta`` (0: white)."""
        if self.envs_per_worker:
            k = self.envs_per_worker
            reset_seeds = [list(reset_seeds[i:i + k]) for i in range(0, self.num_envs, k)]
            noise_seeds_ = [list(noise_seeds_[i:i + k]) for i in range(0, self.num_envs, k)]
        self._ask_all("reset", [(r, n, noise_beta, noise_horizon) for r, n in zip(reset_seeds, noise_seeds_)])

    def rollout(self, weights: dict[str, np.ndarray], steps: int) -> dict[str, np.ndarray]:
        """``steps`` steps of every environment; arrays shaped ``(steps, num_envs, ...)``."""
        segments = self._ask_all("rollout", [(weights, steps)] * self.num_workers)
        join = np.concatenate if self.envs_per_worker else np.stack
        return {key: join([s[key] for s in segments], axis=1) for key in segments[0]}

    def call(self, name: str) -> list[Any]:
        """``name()`` of every worker's (info-dropping) environment wrapper, as the vector envs' ``call``."""
        return self._ask_all("call", [name] * self.num_workers)

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        for index, pipe in enumerate(self._pipes):
            try:
                pipe.send(("close", None))
                pipe.recv()
            except (BrokenPipeError, EOFError, OSError):
                pass
        for process in self._processes:
            process.join(timeout=5)
            if process.is_alive():
                process.kill()

    def __del__(self) -> None:  # a trainer that raised still stops its workers
        try:
            self.close()
        except Exception:  # noqa: BLE001 - interpreter shutdown
            pass
