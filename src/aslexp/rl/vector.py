"""Many environments for one learner: gymnasium vector environments, built the way PPO needs them.

``make_vector_env(env, num_envs, mode)`` returns a :class:`gymnasium.vector.VectorEnv` with
same-step autoreset (a finished episode's last observation is in ``info["final_obs"]``, the
returned one already starts the next episode: PPO bootstraps a truncated episode from the former):

* ``sync``: the environments step one after another in this process (``SyncVectorEnv``); with
  one environment this is the default, and the fastest: no inter-process round trip.
* ``async``: one worker process per environment (``AsyncVectorEnv``, observations in shared
  memory); the learner batches the policy over all of them and waits for the slowest, at every
  step (lockstep). ``auto`` picks it only when the rollout runs on the learner's device.
* ``workers`` (:mod:`aslexp.rl.workers`, not a gymnasium vector environment): one process per
  environment with its own copy of the policy, one round trip per rollout; ``auto`` for N > 1.

Why gymnasium's ``AsyncVectorEnv`` and not torchrl's ``ParallelEnv``/collectors: on the hand
(``ImitationEnv``, reference actions, no policy), on this 2-core machine shared with other work,
medians of 2 x 1,500 steps, control steps/s (``python bench/ppo_scaling.py --backends``; the
first two columns from the same measurement in a scratch script at load 1.6-1.8, the last two
from the benchmark at load 4-7):

=====================  ======  ======  ======  ======
control rate           30 Hz   240 Hz  30 Hz   240 Hz
=====================  ======  ======  ======  ======
one env, in process    1,316   1,789   356     690
SyncVectorEnv, N = 1   964     1,856   411     547
AsyncVectorEnv, N = 1  604     1,075   380     326
AsyncVectorEnv, N = 2  1,007   1,608   238     507
ParallelEnv, N = 1     437     634     73      120
ParallelEnv, N = 2     433     704     91      111
=====================  ======  ======  ======  ======

The load makes the absolute figures and the N = 2 gain unreliable (two busy processes ran 1.07x
as fast as one on these "2 cores" at the time), but in every measurement torchrl's
``ParallelEnv`` stepped 1.4-5x slower than ``AsyncVectorEnv``: it builds and checks TensorDicts
on both sides of the pipe for every step, where ``AsyncVectorEnv`` sends the action through a
pipe and the observation through shared memory. A torchrl collector would run a copy of the
policy in each worker: no batched inference (the learner's device is of no use during the
rollout) and the same per-step TensorDict cost.

The environments' per-step ``info`` is dropped (:class:`DropInfo`): merging ~15 reward-term
entries into vector infos costs 17 us per environment step (SyncVectorEnv, measured), and
training reads the terms from the environments' own running sums (``pop_term_means``) instead.

Workers start with ``forkserver`` where the platform has it (``spawn`` otherwise): never
``fork``, which would copy the learner's threads and the engine's clients into every worker. The
environment must therefore come as a picklable factory (``functools.partial(ImitationEnv, ...)``);
an environment instance can only be stepped in this process (``sync``, one environment). The
forkserver preloads the workers' modules (:func:`worker_context`): after a process's first workers,
two more start in 0.4-0.7 s rather than the ~4 s of importing torch and torchrl again (2 cores).
"""

from __future__ import annotations

import functools
import multiprocessing
import os
from collections import defaultdict
from collections.abc import Callable
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.vector import AsyncVectorEnv, AutoresetMode, SyncVectorEnv, VectorEnv

# workers: aslexp.rl.workers (the policy in each worker); batched: one vector environment that steps
# every environment together (aslexp.envs.batched, on an engine that batches; the imitate job's auto picks it there)
MODES = ("auto", "sync", "async", "workers", "batched")
START_METHOD = "forkserver" if "forkserver" in multiprocessing.get_all_start_methods() else "spawn"


def worker_context(factory: Any = None) -> multiprocessing.context.BaseContext:
    """The context worker processes start from. Under forkserver the server imports the workers'
    modules once (torch, torchrl's modules, the environment's module: ~3 s of imports a process) and
    every later worker forks from it without importing them again. The server is one per process,
    single-threaded and holds no engine client; the first call's modules are the ones it loads (a
    worker imports what is missing itself)."""
    context = multiprocessing.get_context(START_METHOD)
    if START_METHOD == "forkserver":
        context.set_forkserver_preload(["aslexp.rl.workers", *_aslexp_modules_of(factory)])
    return context


def _aslexp_modules_of(factory: Any) -> list[str]:
    """The aslexp module a factory comes from (through functools.partial), if any."""
    while isinstance(factory, functools.partial):
        factory = factory.func
    module = getattr(factory, "__module__", "") or ""
    return [module] if module.startswith("aslexp.") else []


class DropInfo(gym.Wrapper):
    """Returns an empty ``info`` from ``step`` and ``reset`` (training reads none of it), and
    reads the environment's running statistics where it keeps them (``{}`` where it does not)."""

    def step(self, action):
        obs, reward, terminated, truncated, _ = self.env.step(action)
        return obs, reward, terminated, truncated, {}

    def reset(self, **kwargs):
        obs, _ = self.env.reset(**kwargs)
        return obs, {}

    def _optional(self, name: str) -> Any:
        try:
            return self.env.get_wrapper_attr(name)
        except AttributeError:
            return None

    def term_means(self) -> dict[str, float]:
        """``pop_term_means()`` of an :class:`~aslexp.envs.imitation.ImitationEnv`: mean reward and
        terms since the last call."""
        pop = self._optional("pop_term_means")
        return dict(pop()) if pop is not None else {}

    def counter_values(self) -> dict[str, int]:
        """A copy of the environment's ``counters`` (episodes, NaN actions, divergences, early ends)."""
        return dict(self._optional("counters") or {})


class _DropInfoFactory:
    """Picklable ``lambda: DropInfo(make_env())`` for worker processes."""

    def __init__(self, make_env: Callable[[], gym.Env]) -> None:
        self.make_env = make_env

    def __call__(self) -> gym.Env:
        return DropInfo(self.make_env())


def cpu_cores() -> int:
    """Cores this process may run on (its affinity mask where the platform has one)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def resolve_mode(mode: str, num_envs: int, rollout_device: str = "cpu") -> str:
    """``auto``: ``sync`` for one environment; for more, ``workers`` (the policy in every worker,
    :mod:`aslexp.rl.workers`: one round trip per rollout, measured faster than lockstep workers
    in bench/ppo_scaling.py) unless the rollout's inference is to run on the learner's device
    (``rollout_device: learner``, e.g. a GPU batching every environment's step): then ``async``."""
    if mode not in MODES:
        raise ValueError(f"ppo config: vector_env must be one of {list(MODES)}, got {mode!r}")
    if mode == "auto":
        if num_envs == 1:
            return "sync"
        return "async" if rollout_device == "learner" else "workers"
    return mode


def make_vector_env(env: gym.Env | Callable[[], gym.Env], num_envs: int = 1, mode: str = "auto") -> VectorEnv:
    """``num_envs`` copies of ``env`` (an environment factory, or an instance for one in-process env)."""
    if num_envs < 1:
        raise ValueError(f"ppo config: num_envs must be at least 1, got {num_envs}")
    mode = resolve_mode(mode, num_envs)
    if mode == "batched":
        if isinstance(env, gym.Env) or not callable(env):
            raise ValueError("ppo config: vector_env batched needs a factory of batched environments "
                             "(functools.partial(BatchedImitationEnv, motion=...)), got an environment instance")
        envs = env(num_envs)
        if not isinstance(envs, VectorEnv) or envs.num_envs != num_envs:
            raise ValueError(f"ppo config: vector_env batched: the factory gave {type(envs).__name__}, "
                             f"expected a vector environment of {num_envs}")
        return envs
    if isinstance(env, gym.Env):
        if num_envs != 1 or mode != "sync":
            raise ValueError(f"ppo config: num_envs={num_envs} (vector_env {mode}) needs an environment factory "
                             f"(a picklable callable such as functools.partial(ImitationEnv, ...)), "
                             f"got an environment instance")
        instance = env
        factories = [lambda: DropInfo(instance)]
    elif callable(env):
        factories = [_DropInfoFactory(env) for _ in range(num_envs)]
    else:
        raise TypeError(f"expected a gymnasium environment or a factory, got {type(env).__name__}")
    if mode == "sync":
        return SyncVectorEnv(factories, copy=False, autoreset_mode=AutoresetMode.SAME_STEP)
    worker_context(env)  # the forkserver's preloaded modules, before its first worker
    return AsyncVectorEnv(factories, shared_memory=True, copy=False, context=START_METHOD,
                          autoreset_mode=AutoresetMode.SAME_STEP)


def worker_seeds(seed: int, num_envs: int, start_step: int = 0) -> list[int]:
    """Reset seeds of the environments of a run: deterministic per (seed, worker, start step).

    numpy's ``SeedSequence`` rather than ``seed + worker``: with the latter, worker 1 of the run
    with seed 0 replays worker 0 of the run with seed 1, and runs meant to be independent share
    streams. A resumed run (``start_step`` > 0) draws fresh streams instead of replaying the
    first episodes of the run it continues.
    """
    return [int(np.random.SeedSequence([seed, worker, start_step]).generate_state(1)[0])
            for worker in range(num_envs)]


def sum_counters(envs: VectorEnv) -> dict[str, int]:
    """The environments' ``counters`` (episodes, early ends, ...) summed over workers."""
    total: dict[str, int] = defaultdict(int)
    for counters in envs.call("counter_values"):
        for key, value in counters.items():
            total[key] += int(value)
    return dict(total)


def mean_terms(envs: VectorEnv) -> dict[str, float]:
    """Mean training reward and terms since the last call, over all environments.

    Each environment's ``pop_term_means`` is a mean over its own steps; in a rollout every
    environment takes the same number of steps, so the plain mean over environments is the mean
    over all steps.
    """
    per_env = [m for m in envs.call("term_means") if m]
    if not per_env:
        return {}
    return {key: float(np.mean([m[key] for m in per_env if key in m])) for key in per_env[0]}
