"""PPO for imitation, CleanRL-style: collect a rollout, GAE, clipped-surrogate epochs, repeat.

Collection steps ``num_envs`` environments: one in this process by default; with more, one worker
process each, either with a copy of the policy that steps a whole rollout per message
(``vector_env: workers``, the default for N > 1: :mod:`aslexp.rl.workers`) or in lockstep with the
policy batched over all environments here (``async``: gymnasium's ``AsyncVectorEnv``;
:mod:`aslexp.rl.vector` says why not torchrl's ``ParallelEnv``). Each environment keeps its own
episode (returns, lengths, and same-step resets: a truncated episode is bootstrapped from its
last observation, a terminated one is not). The rollout becomes a ``(num_envs, steps)`` TensorDict and the
learning side is torchrl's: :class:`~torchrl.objectives.value.GAE` (time is the last batch
dimension) and :class:`~torchrl.objectives.ClipPPOLoss`, on ``device`` (``auto``: CUDA when
there is one). Rollout inference stays on the CPU by default (``rollout_device``): a batch of a
few observations per step is faster there than a round trip to a GPU.

``steps_per_rollout`` is the whole batch of one update, shared by the environments
(``ceil(steps_per_rollout / num_envs)`` steps each): ``num_envs`` changes the speed, not the
algorithm. (Stable-Baselines3's ``n_steps`` is per environment: the thesis code's 10 environments
x ``n_steps`` 4096 is ``steps_per_rollout: 40960`` here.)

Exploration is the Gaussian policy's noise, white by default; ``noise_beta`` > 0 correlates it over
time (:mod:`aslexp.rl.noise`: pink, red), each environment drawing from its own seeded sequence in
every collection mode.

Every ``eval_interval`` environment steps the policy is evaluated deterministically from
``eval_episodes`` start phases (``on_eval(step, reward, row)`` is called: the job reports to the
sweep there) and a checkpoint is written; ``resume_from`` continues a run from its checkpoint.
The headline is ``last_eval`` (mean of the last ``eval_last_k`` evaluations), never the best
of many; ``best_eval`` is kept beside it. After every update ``on_progress(row)`` receives the
row written to progress.csv (for loggers), and a log line with steps, steps/s and ETA is
written at least every ``progress_interval`` seconds of work.
"""

from __future__ import annotations

import copy
import csv
import functools
import io
import logging
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch
from tensordict import TensorDict
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.value import GAE

from aslexp.config_schema import PPO, read
from aslexp.files import atomic_path
from aslexp.rl.checkpoint import load_checkpoint, save_checkpoint
from aslexp.rl.evaluate import EvaluationSummary, even_phases, evaluate_phases
from aslexp.rl.noise import ActionNoise
from aslexp.rl.policy import Agent, ModelSpec
from aslexp.rl.vector import cpu_cores, make_vector_env, mean_terms, resolve_mode, sum_counters, worker_seeds
from aslexp.rl.workers import PolicyWorkers, actor_state, noise_seeds

log = logging.getLogger("aslexp.ppo")
LOG_PROB = "action_log_prob"


@dataclass(frozen=True)
class PPOConfig:
    """``conf/ppo/*.yaml`` as plain values (``conf/ppo/base.yaml`` documents every key)."""

    name: str = "custom"
    hidden_sizes: tuple[int, ...] = (1024, 1024)
    actor_hidden_sizes: tuple[int, ...] | None = None  # None: hidden_sizes; []: a linear policy
    # How a policy sample becomes the env's action (aslexp.rl.policy): box (aslexp's, affine onto the
    # action box) | sb3 (SB3 1.6, the authors' library: the sample in the action's units, clipped).
    action_mapping: str = "box"
    activation: str = "relu"
    learning_rate: float = 3e-4
    # Linear schedules over total_steps, set before each rollout (None: constant learning rate; a
    # learned log-std). With log_std_final the noise is not learned but follows the schedule, as
    # DeepMimic's fixed exploration noise: the policy PPO optimises late is close to the
    # deterministic one that is evaluated.
    learning_rate_final: float | None = None
    log_std_final: float | None = None
    steps_per_rollout: int = 4096  # per update, all environments together
    minibatch_size: int = 256
    epochs: int = 3
    gamma: float = 0.95
    gae_lambda: float = 0.95
    clip_epsilon: float = 0.2
    entropy_coef: float = 0.0
    value_coef: float = 5.0
    max_grad_norm: float = 100.0
    target_kl: float | None = 0.05
    # How the KL early stop reads the policy's move on each minibatch: "torchrl", mean(log pi_old -
    # log pi), checked after the minibatch's step; "sb3", Stable-Baselines3 1.6's mean((r - 1) - log r)
    # checked before it (the minibatch that passes the limit is not applied), as the authors' scripts ran.
    kl_stop: str = "torchrl"
    log_std_init: float = -3.0
    # Colour of the exploration noise (aslexp.rl.noise): 0 white, independent at every step; > 0
    # correlated over time with a power spectrum ~ 1/f^beta (1: pink) over noise_horizon steps.
    noise_beta: float = 0.0
    noise_horizon: int = 300
    ortho_init: bool = True
    weight_decay: float = 1e-5
    total_steps: int = 50_000_000
    eval_interval: int = 50_000
    eval_steps: int = 300
    eval_episodes: int = 4  # deterministic episodes per evaluation, from phases 0, 1/n, 2/n, ...
    eval_phases: tuple[float, ...] | None = None  # explicit start phases (then eval_episodes is unused)
    eval_last_k: int = 1  # the headline last_eval is the mean of the last k evaluations
    # Evaluate the untrained policy before the first update (a curve's step 0: the level learning
    # starts from); never part of last_eval or best_eval.
    eval_at_start: bool = False
    max_minutes: float | None = None
    target_reward: float | None = None  # stop once the headline evaluation reward exceeds this
    # Environment steps during which only the critic learns: a policy that starts near a good
    # controller (residual actions) is otherwise moved by advantages that are mostly critic error.
    critic_warmup_steps: int = 0
    num_envs: int = 1
    vector_env: str = "auto"  # auto (sync for 1 env, workers for more) | sync | async | workers | batched
    # vector_env batched: worker processes, each stepping num_envs / batched_workers environments with
    # its own copy of the policy (one round trip per rollout); 0: every environment in this process.
    batched_workers: int = 0
    device: str = "auto"  # the learner's: auto (cuda if available) | cpu | cuda | cuda:N
    rollout_device: str = "cpu"  # policy inference while collecting: cpu | learner
    # The evaluations step one environment and ask the policy for one action at a time: on the CPU
    # that is ~0.3 ms for a 2 x 1024 MLP; on a GPU shared by 15 runs it measured 3.6 ms (docs/engines.md).
    eval_device: str = "cpu"  # cpu | learner
    torch_threads: int = 1
    progress_interval: float = 5.0  # seconds of work between progress log lines

    def __post_init__(self) -> None:
        checks = [("num_envs", self.num_envs >= 1, "at least 1"),
                  ("steps_per_rollout", self.steps_per_rollout >= self.num_envs, f"at least num_envs ({self.num_envs})"),
                  ("eval_episodes", self.eval_episodes >= 1, "at least 1"),
                  ("eval_last_k", self.eval_last_k >= 1, "at least 1"),
                  ("noise_beta", self.noise_beta >= 0, "at least 0 (0: white noise, 1: pink)"),
                  ("noise_horizon", self.noise_horizon >= 2, "at least 2 steps"),
                  ("learning_rate_final", self.learning_rate_final is None or self.learning_rate_final >= 0,
                   "null or at least 0"),
                  ("rollout_device", self.rollout_device in ("cpu", "learner"), "cpu or learner"),
                  ("eval_device", self.eval_device in ("cpu", "learner"), "cpu or learner"),
                  ("kl_stop", self.kl_stop in ("torchrl", "sb3"), "torchrl or sb3"),
                  ("eval_phases", self.eval_phases is None or (len(self.eval_phases) > 0 and all(
                      0.0 <= p < 1.0 for p in self.eval_phases)), "null or a non-empty list of phases in [0, 1)")]
        for key, ok, expected in checks:
            if not ok:
                raise ValueError(f"ppo config: {key} must be {expected}, got {getattr(self, key)!r}")
        resolve_mode(self.vector_env, self.num_envs, self.rollout_device)
        if self.batched_workers and (self.batched_workers < 0 or self.num_envs % self.batched_workers):
            raise ValueError(f"ppo config: batched_workers must be 0 or a divisor of num_envs ({self.num_envs}), "
                             f"got {self.batched_workers!r}")
        resolve_device(self.device)  # an unknown or absent device fails here, before any work

    @classmethod
    def parse(cls, values: dict[str, Any] | None, section: str = "ppo") -> "PPOConfig":
        """Types and ranges: aslexp.config_schema.PPO (the jobs check the same before anything runs)."""
        return read(cls, values, section, PPO)

    @property
    def model(self) -> ModelSpec:
        return ModelSpec(self.hidden_sizes, self.activation, self.ortho_init, self.log_std_init,
                         self.actor_hidden_sizes, self.action_mapping)

    def scheduled(self, steps: int) -> tuple[float, float | None]:
        """(learning rate, log-std or None: learned) at ``steps`` environment steps."""
        fraction = min(max(steps / self.total_steps, 0.0), 1.0) if self.total_steps > 0 else 1.0

        def linear(start: float, end: float | None) -> float | None:
            return None if end is None else start + fraction * (end - start)

        lr = linear(self.learning_rate, self.learning_rate_final)
        return (self.learning_rate if lr is None else lr), linear(self.log_std_init, self.log_std_final)

    @property
    def steps_per_env(self) -> int:
        return math.ceil(self.steps_per_rollout / self.num_envs)

    @property
    def batch_size(self) -> int:
        """Transitions per update: ``steps_per_rollout`` rounded up to a multiple of ``num_envs``."""
        return self.steps_per_env * self.num_envs

    @property
    def phases(self) -> tuple[float, ...]:
        """Start phases of the evaluation episodes."""
        return self.eval_phases if self.eval_phases is not None else even_phases(self.eval_episodes)

    @property
    def eval_protocol(self) -> dict[str, Any]:
        """How an evaluation is made, for metrics files and reports."""
        return {"episodes": len(self.phases), "phases": list(self.phases), "steps": self.eval_steps,
                "last_k": self.eval_last_k, "deterministic": True}


def resolve_device(name: str) -> torch.device:
    """``auto`` -> CUDA if torch sees a GPU, else CPU; an unavailable device is an error."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        device = torch.device(name)
    except RuntimeError as exc:
        raise ValueError(f"ppo config: device must be auto, cpu, cuda or cuda:N, got {name!r}") from exc
    if device.type == "cuda" and not torch.cuda.is_available():
        raise ValueError(f"ppo config: device {name!r} but torch {torch.__version__} finds no CUDA device "
                         f"(use ppo.device=auto or cpu)")
    return device


@dataclass
class TrainResult:
    steps: int
    seconds: float
    best_eval: float  # the best single evaluation (secondary: a maximum over noisy evaluations)
    last_eval: float  # the headline: mean of the last eval_last_k evaluations
    history: list[dict[str, Any]] = field(default_factory=list)
    stopped: str = "total_steps"  # total_steps | max_minutes | target_reward


def loss_and_optimizer(agent: Agent, config: PPOConfig, device: torch.device) -> tuple[ClipPPOLoss, torch.optim.Adam]:
    """The trainer's clipped-PPO loss over ``agent`` and the Adam that steps its parameters (a
    checkpoint's ``optimizer`` is this Adam's state: stacked runs write theirs through it)."""
    loss = ClipPPOLoss(
        agent.actor, agent.critic, clip_epsilon=config.clip_epsilon,
        entropy_bonus=config.entropy_coef > 0, entropy_coeff=config.entropy_coef or None,
        critic_coeff=config.value_coef, loss_critic_type="l2", normalize_advantage=True, device=device,
    )
    loss.set_keys(sample_log_prob=LOG_PROB)
    # On a GPU one fused kernel steps every parameter (the update is 800 small steps in Table D.1).
    optimizer = torch.optim.Adam(loss.parameters(), lr=config.learning_rate, weight_decay=config.weight_decay,
                                 fused=device.type == "cuda")
    return loss, optimizer


def make_agent(env, config: PPOConfig) -> Agent:
    """An agent for an environment (or a vector environment: its single spaces)."""
    if hasattr(env, "single_observation_space"):
        return agent_for_spaces(config.model, env.single_observation_space, env.single_action_space)
    return agent_for_spaces(config.model, env.observation_space, env.action_space)


def agent_for_spaces(model: ModelSpec, obs_space: gym.Space, act_space: gym.Space) -> Agent:
    """An agent of architecture ``model`` for these spaces (picklable with functools.partial:
    rollout workers build their policy copy with it)."""
    low, high = act_space.low.astype(np.float64), act_space.high.astype(np.float64)
    return Agent(obs_space.shape[0], act_space.shape[0], model, (low + high) / 2, (high - low) / 2)


class EpisodeStats:
    """Per-environment running return and length; the episodes that ended since the last pop."""

    def __init__(self, num_envs: int) -> None:
        self.returns = np.zeros(num_envs)
        self.lengths = np.zeros(num_envs, dtype=np.int64)
        self.ended: list[tuple[float, int, bool]] = []  # (return, length, terminated)

    def step(self, rewards: np.ndarray, terminated: np.ndarray, truncated: np.ndarray) -> None:
        self.returns += rewards
        self.lengths += 1
        for i in np.flatnonzero(terminated | truncated):
            self.ended.append((float(self.returns[i]), int(self.lengths[i]), bool(terminated[i])))
            self.returns[i], self.lengths[i] = 0.0, 0

    def pop(self) -> dict[str, float]:
        """Means over the episodes that ended (none: an empty dict, never a made-up value)."""
        if not self.ended:
            return {}
        returns, lengths, terminated = (np.asarray(v) for v in zip(*self.ended))
        self.ended = []
        return {"episodes": len(returns), "episode_return": float(returns.mean()),
                "episode_length": float(lengths.mean()), "episode_terminated": float(terminated.mean())}


class Progress:
    """A log line with steps, steps/s and ETA at least every ``interval`` seconds of work."""

    def __init__(self, config: PPOConfig, start_steps: int, elapsed_before: float) -> None:
        self.config = config
        self.start_steps, self.elapsed_before = start_steps, elapsed_before
        self.start = self.last = time.perf_counter()
        self.note = ""  # appended to each line (the last evaluation)

    def elapsed(self) -> float:
        """Training seconds of the run, earlier processes included (what max_minutes counts)."""
        return self.elapsed_before + time.perf_counter() - self.start

    def rate(self, steps: int) -> float:
        return (steps - self.start_steps) / max(time.perf_counter() - self.start, 1e-9)

    def tick(self, steps: int) -> None:
        if time.perf_counter() - self.last >= self.config.progress_interval:
            self.report(steps)

    def report(self, steps: int) -> None:
        cfg, rate = self.config, self.rate(steps)
        eta, limit = max(cfg.total_steps - steps, 0) / max(rate, 1e-9), "total_steps"
        if cfg.max_minutes is not None and 60 * cfg.max_minutes - self.elapsed() < eta:
            eta, limit = max(60 * cfg.max_minutes - self.elapsed(), 0.0), "max_minutes"
        log.info("step %s/%s (%.0f%%)  %s steps/s  ETA %s (%s)%s", f"{steps:,}", f"{cfg.total_steps:,}",
                 100 * steps / max(cfg.total_steps, 1), f"{rate:,.0f}", _duration(eta), limit, self.note)
        self.last = time.perf_counter()


class PPOTrainer:
    """Owns the agent, the optimiser, the loss, the training environments and the run's state.

    ``env`` is an environment factory (a picklable callable; required for ``num_envs`` > 1) or,
    for one environment in this process, an environment instance (left open: the caller owns it).
    ``eval_env`` is an environment instance (``None``: no evaluation, e.g. in benchmarks).
    """

    def __init__(self, env: gym.Env | Callable[[], gym.Env], eval_env, config: PPOConfig, out_dir: str | Path,
                 seed: int = 0, on_eval: Callable[[int, float, dict[str, Any]], None] | None = None,
                 on_progress: Callable[[dict[str, Any]], None] | None = None,
                 validate: Callable[[Agent], float] | None = None) -> None:
        torch.set_num_threads(max(1, int(config.torch_threads)))
        self.config, self.eval_env = config, eval_env
        self.device = resolve_device(config.device)
        self.out_dir = Path(out_dir)
        self.out_dir.mkdir(parents=True, exist_ok=True)
        self.on_eval, self.on_progress = on_eval, on_progress
        # Early stopping: ``validate(agent)`` scores the policy on motions that neither train nor are
        # evaluated, at every evaluation; the best-validated policy is kept (checkpoints/selected.pt) and
        # is the one the run ends with, evaluated once more as the last row (``selected_step`` in it).
        self.validate = validate
        self.best_validation = -math.inf
        self.selected_step: int | None = None
        self.ended_on_selected = False  # the last row evaluates the selected policy: it alone is last_eval
        torch.manual_seed(seed)
        self.rng = np.random.default_rng(seed)
        self.seed = seed
        self.mode = resolve_mode(config.vector_env, config.num_envs, config.rollout_device)
        if self.mode in ("async", "workers"):
            cores = cpu_cores()
            log.info("starting %d environment worker process(es)%s", config.num_envs,
                     f" on {cores} cores: they will share them" if config.num_envs > cores else "")
        if self.mode == "batched" and config.batched_workers:
            self.mode = "workers"  # the workers' collection, each worker a batch on one thread
            log.info("starting %d rollout worker process(es), %d environments each", config.batched_workers,
                     config.num_envs // config.batched_workers)
            self.envs = PolicyWorkers(functools.partial(env, threads=1), config.num_envs,
                                      functools.partial(agent_for_spaces, config.model),
                                      envs_per_worker=config.num_envs // config.batched_workers)
        elif self.mode == "workers":
            if isinstance(env, gym.Env) or not callable(env):
                raise ValueError("ppo config: vector_env workers needs an environment factory (a picklable "
                                 "callable such as functools.partial(ImitationEnv, ...)), got an environment instance")
            self.envs = PolicyWorkers(env, config.num_envs, functools.partial(agent_for_spaces, config.model))
        else:
            self.envs = make_vector_env(env, config.num_envs, config.vector_env)
        self._owns_envs = not isinstance(env, gym.Env)
        self.num_envs = config.num_envs
        self.agent = make_agent(self.envs, config).to(self.device)
        # The policy that collects: the learner's own, or a CPU copy refreshed after every update.
        same = config.rollout_device == "learner" or self.device.type == "cpu"
        self.rollout_agent = self.agent if same else copy.deepcopy(self.agent).cpu()
        self.loss, self.optimizer = loss_and_optimizer(self.agent, config, self.device)
        self.gae = GAE(gamma=config.gamma, lmbda=config.gae_lambda, value_network=self.agent.critic,
                       average_gae=False, device=self.device)
        if config.log_std_final is not None:  # the noise follows its schedule: no gradient moves it
            self.agent.head.log_std.requires_grad_(False)
        self.steps = 0
        self.iteration = 0
        self.elapsed = 0.0  # training seconds before this process (resume)
        self.best_eval = -math.inf
        self.history: list[dict[str, Any]] = []
        self.episodes = EpisodeStats(self.num_envs)
        self.progress: Progress | None = None
        # Episodes run on across rollouts; a new run or a resumed one starts them all again.
        self._episodes_started = False
        self._obs: np.ndarray | None = None  # in-process collection: the environments' current observations
        self._noise: list[ActionNoise] = []  # in-process collection with coloured noise: one per environment
        self._eval_agent: Agent | None = None  # the evaluations' CPU copy (eval_device: cpu, learner elsewhere)
        self.last_evaluation: EvaluationSummary | None = None  # the newest evaluate()'s, divergences included

    def close(self) -> None:
        """Stop the worker processes (an environment instance passed in stays open)."""
        if self._owns_envs:
            self.envs.close()

    def counters(self) -> dict[str, int]:
        """Episodes, NaN actions, divergences and early ends, summed over the training environments."""
        return sum_counters(self.envs)

    # -- checkpoints ----------------------------------------------------------------------
    def state(self) -> dict[str, Any]:
        return {
            "agent": self.agent.state_dict(), "optimizer": self.optimizer.state_dict(),
            "steps": self.steps, "iteration": self.iteration, "elapsed": self.elapsed,
            "best_eval": self.best_eval, "history": self.history, "config": asdict(self.config),
            "best_validation": self.best_validation, "selected_step": self.selected_step,
            "seed": self.seed, "torch_rng": torch.get_rng_state(), "numpy_rng": self.rng.bit_generator.state,
            "num_envs": self.num_envs, "device": str(self.device),  # informative: any other value resumes
        }

    def save(self, name: str = "last.pt") -> Path:
        return save_checkpoint(self.out_dir / "checkpoints" / name, self.state())

    def restore(self, path: str | Path) -> None:
        """Continue from a checkpoint (written with any ``num_envs`` or device). The environments
        start new episodes: their state is not saved, so a resumed run is not bit-identical to
        an uninterrupted one."""
        payload = load_checkpoint(path)
        try:
            self.agent.load_state_dict(payload["agent"])
            self.optimizer.load_state_dict(payload["optimizer"])
        except (KeyError, RuntimeError, ValueError) as exc:
            raise ValueError(f"checkpoint {path} does not fit this model/config: {exc}") from exc
        self.steps, self.iteration = int(payload["steps"]), int(payload["iteration"])
        self.elapsed, self.best_eval = float(payload["elapsed"]), float(payload["best_eval"])
        self.history = list(payload["history"])
        self.best_validation = float(payload.get("best_validation", -math.inf))
        self.selected_step = payload.get("selected_step")
        torch.set_rng_state(payload["torch_rng"])
        self.rng.bit_generator.state = payload["numpy_rng"]
        self._sync_rollout_agent()
        self._episodes_started, self._obs = False, None
        log.info("resumed from %s at step %d (saved with %s environment(s), now %d)", path, self.steps,
                 payload.get("num_envs", 1), self.num_envs)

    def load_policy(self, path: str | Path) -> None:
        """The agent's weights (and observation statistics) of a checkpoint, nothing else: a trained
        policy performing another motion (``aslexp imitate policy=RUN_DIR``) starts no training state."""
        payload = load_checkpoint(path)
        try:
            self.agent.load_state_dict(payload["agent"])
        except (KeyError, RuntimeError, ValueError) as exc:
            raise ValueError(f"checkpoint {path} does not fit this model/config: {exc}") from exc
        self._sync_rollout_agent()
        log.info("policy from %s (trained %d steps)", path, int(payload.get("steps", 0)))

    def apply_schedules(self) -> dict[str, float]:
        """Set the learning rate and (if scheduled) the log-std for the next update."""
        lr, log_std = self.config.scheduled(self.steps)
        for group in self.optimizer.param_groups:
            group["lr"] = lr
        if log_std is not None:
            with torch.no_grad():
                self.agent.head.log_std.fill_(log_std)
            self._sync_rollout_agent()
        return {"learning_rate": lr}

    def _sync_rollout_agent(self) -> None:
        if self.rollout_agent is not self.agent:
            self.rollout_agent.load_state_dict(self.agent.state_dict())

    # -- rollout ----------------------------------------------------------------------------
    def collect(self) -> TensorDict:
        """One rollout: ``steps_per_env`` steps of every environment as a ``(num_envs, steps)``
        TensorDict of normalised observations (on the rollout device)."""
        if self.mode == "workers":
            return self._collect_in_workers()
        envs, agent, n_envs, n = self.envs, self.rollout_agent, self.num_envs, self.config.steps_per_env
        device = agent.device
        obs_size, act_size = envs.single_observation_space.shape[0], envs.single_action_space.shape[0]
        raw_obs = np.empty((n, n_envs, obs_size), np.float32)
        next_raw = np.empty((n, n_envs, obs_size), np.float32)
        actions = torch.empty(n, n_envs, act_size, device=device)
        rewards = np.empty((n, n_envs), np.float32)
        terminated = np.empty((n, n_envs), bool)
        done = np.empty((n, n_envs), bool)
        coloured = self.config.noise_beta > 0
        if not self._episodes_started:
            self._obs, _ = envs.reset(seed=worker_seeds(self.seed, n_envs, self.steps))
            self.episodes = EpisodeStats(n_envs)
            self._episodes_started = True
            if coloured:  # white noise stays torch's global stream, as it always was
                self._noise = [ActionNoise(act_size, s, self.config.noise_beta, self.config.noise_horizon)
                               for s in noise_seeds(self.seed, n_envs, self.steps)]
        with torch.no_grad():
            for t in range(n):
                raw_obs[t] = self._obs
                loc, scale = agent.head(agent.normalizer(torch.from_numpy(raw_obs[t]).to(device)))
                eps = torch.stack([noise.sample() for noise in self._noise]).to(device) if coloured \
                    else torch.randn_like(loc)
                a = loc + scale * eps
                actions[t] = a
                obs, reward, term, trunc, info = envs.step(agent.to_env_action(a).cpu().numpy())
                next_raw[t] = obs
                ended = term | trunc
                for i in np.flatnonzero(ended):  # same-step reset: obs already starts the next episode
                    next_raw[t, i] = info["final_obs"][i]
                    if coloured:
                        self._noise[i].restart()
                rewards[t], terminated[t], done[t] = reward, term, ended
                self.episodes.step(reward, term, trunc)
                self._obs = obs
                if self.progress is not None:
                    self.progress.tick(self.steps + (t + 1) * n_envs)
        return self._batch(raw_obs, next_raw, actions, rewards, terminated, done)

    def _collect_in_workers(self) -> TensorDict:
        """The rollout with the policy in the workers (``vector_env: workers``): one message per
        worker and rollout; the same batch as :meth:`collect`'s."""
        n = self.config.steps_per_env
        if not self._episodes_started:  # the observations live in the workers
            self.envs.reset(worker_seeds(self.seed, self.num_envs, self.steps),
                            noise_seeds(self.seed, self.num_envs, self.steps),
                            self.config.noise_beta, self.config.noise_horizon)
            self.episodes = EpisodeStats(self.num_envs)
            self._episodes_started = True
        segment = self.envs.rollout(actor_state(self.agent), n)
        for t in range(n):
            self.episodes.step(segment["reward"][t], segment["terminated"][t], segment["truncated"][t])
        if self.progress is not None:
            self.progress.tick(self.steps + n * self.num_envs)
        actions = torch.from_numpy(segment["action"]).to(self.rollout_agent.device)
        return self._batch(segment["obs"], segment["next_obs"], actions, segment["reward"], segment["terminated"],
                           segment["terminated"] | segment["truncated"])

    def _batch(self, raw_obs: np.ndarray, next_raw: np.ndarray, actions: torch.Tensor, rewards: np.ndarray,
               terminated: np.ndarray, done: np.ndarray) -> TensorDict:
        """``(steps, envs)`` arrays of a rollout -> the ``(envs, steps)`` TensorDict PPO learns from,
        observations normalised with the statistics the actions were sampled under (then updated)."""
        agent, n_envs, n = self.rollout_agent, self.num_envs, raw_obs.shape[0]
        device = agent.device
        # (steps, envs) -> (envs, steps): torchrl's GAE takes time as the last batch dimension.
        raw = torch.from_numpy(np.ascontiguousarray(raw_obs.swapaxes(0, 1))).to(device)
        next_raw_t = torch.from_numpy(np.ascontiguousarray(next_raw.swapaxes(0, 1))).to(device)
        actions = actions.transpose(0, 1).contiguous()
        # Normalise with the statistics the actions were taken under, then update them.
        norm = agent.normalizer
        observation, next_observation = norm(raw), norm(next_raw_t)
        with torch.no_grad():  # same parameters as during the rollout: one batched pass
            loc, scale = agent.head(observation)
            log_probs = torch.distributions.Normal(loc, scale).log_prob(actions).sum(-1)
        self.agent.normalizer.update(raw.to(self.device))
        if agent is not self.agent:
            agent.normalizer.load_state_dict(self.agent.normalizer.state_dict())
        self.steps += n * n_envs

        def per_env(values: np.ndarray) -> torch.Tensor:
            return torch.from_numpy(np.ascontiguousarray(values.swapaxes(0, 1))).unsqueeze(-1).to(device)

        return TensorDict({
            "observation": observation, "action": actions, LOG_PROB: log_probs,
            "next": {"observation": next_observation, "reward": per_env(rewards),
                     "done": per_env(done), "terminated": per_env(terminated)},
        }, batch_size=[n_envs, n])

    # -- learning ---------------------------------------------------------------------------
    def learn(self, batch: TensorDict) -> dict[str, float]:
        cfg = self.config
        batch = batch.to(self.device)
        with torch.no_grad():
            self.gae(batch)  # per environment along time; bootstraps unless terminated
        flat = batch.reshape(-1)
        # Plain tensors, indexed per minibatch: a TensorDict index and torchrl's loss module cost
        # ~7 ms of Python per minibatch, the whole update on a GPU (800 minibatches in Table D.1).
        data = MinibatchData(flat["observation"], flat["action"], flat[LOG_PROB], flat["advantage"],
                             flat["value_target"])
        totals = torch.zeros(len(STAT_KEYS), device=self.device)
        updates = seen = 0
        stop = False
        limit = None if cfg.target_kl is None else 1.5 * cfg.target_kl  # both: SB3's 1.5 x target_kl
        params = list(self.loss.parameters())
        for _ in range(cfg.epochs):
            order = torch.from_numpy(self.rng.permutation(len(flat))).to(self.device)
            for start in range(0, len(flat), cfg.minibatch_size):
                losses = clipped_ppo_losses(self.agent, data.take(order[start:start + cfg.minibatch_size]),
                                            cfg.clip_epsilon, cfg.value_coef, cfg.entropy_coef)
                total = minimised_loss(losses, critic_only=self.steps <= cfg.critic_warmup_steps)
                totals += torch.stack([losses[k].detach() for k in STAT_KEYS])
                seen += 1
                # One device sync per minibatch, only when the early stop needs it; the epochs stop
                # once the policy moved too far (SB3: before this minibatch's step, torchrl: after).
                if limit is not None and cfg.kl_stop == "sb3" and float(losses["approx_kl"]) > limit:
                    stop = True
                    break
                self.optimizer.zero_grad()
                total.backward()
                torch.nn.utils.clip_grad_norm_(params, cfg.max_grad_norm)
                self.optimizer.step()
                updates += 1
                if limit is not None and cfg.kl_stop == "torchrl" and float(losses["kl"]) > limit:
                    stop = True
                    break
            if stop:
                break
        self._sync_rollout_agent()
        means = (totals / max(seen, 1)).tolist()
        return dict(zip(STAT_KEYS, means)) | {"updates": updates}

    def evaluate(self) -> EvaluationSummary:
        """Deterministic episodes from the configured start phases (see :func:`evaluate_phases`)."""
        if self.eval_env is None:
            raise ValueError("this trainer has no evaluation environment")
        agent = self.evaluation_agent()
        self.last_evaluation = evaluate_phases(self.eval_env, lambda obs, env: agent.act(obs, deterministic=True),
                                               self.config.eval_steps, self.config.phases)
        return self.last_evaluation

    def evaluation_agent(self) -> Agent:
        """The policy the evaluations ask: the learner's own, or a CPU copy of it (``eval_device: cpu``
        with the learner elsewhere), refreshed from the learner before every evaluation."""
        if self.config.eval_device == "learner" or self.agent.device.type == "cpu":
            return self.agent
        if self.rollout_agent.device.type == "cpu":
            return self.rollout_agent  # already the learner's weights after every update
        if self._eval_agent is None:
            self._eval_agent = copy.deepcopy(self.agent).cpu()
        self._eval_agent.load_state_dict(self.agent.state_dict())
        return self._eval_agent

    @staticmethod
    def _evaluation_row(summary: EvaluationSummary) -> dict[str, Any]:
        return {"eval_reward": round(summary.mean_reward, 5), "eval_reward_std": round(summary.std, 5),
                "eval_reward_min": round(min(summary.rewards), 5), "eval_action_rms": round(summary.action_rms, 5),
                # episodes that blew up: never a score (the results page marks them)
                "eval_diverged": int(summary.diverged),
                **{f"eval_score_{k}": round(v, 5) for k, v in summary.scores.items()},
                **{f"eval_{k}": round(v, 5) for k, v in summary.terms.items()}}

    def _validated(self, row: dict[str, Any]) -> None:
        """``validate``'s score of the current policy in ``row``; a new best is kept as selected.pt."""
        if self.validate is None:
            return
        value = round(float(self.validate(self.evaluation_agent())), 5)
        row["validation_reward"] = value
        if value > self.best_validation:
            self.best_validation, self.selected_step = value, self.steps
            self.save("selected.pt")
        row["selected_step"] = self.selected_step

    def _record_evaluation(self, row: dict[str, Any], elapsed: float, progress: "Progress") -> None:
        """An evaluated row's headline and best, its checkpoints (last.pt, best.pt on a new best) and
        its progress line."""
        self.elapsed = elapsed
        row["last_eval"] = round(self.last_eval(), 5)
        if row["eval_reward"] > self.best_eval:  # rounded as last_eval is: they compare exactly
            self.best_eval = row["eval_reward"]
            self.save("best.pt")
        row["best_eval"] = round(self.best_eval, 5)
        self.save("last.pt")
        progress.note = f"  eval {row['eval_reward']:.4f} (last {row['last_eval']:.4f}, best {self.best_eval:.4f})"
        if "validation_reward" in row:
            chosen = "none" if self.selected_step is None else f"{self.selected_step:,}"
            progress.note += (f"  validation {row['validation_reward']:.4f} (best {self.best_validation:.4f}, "
                              f"step {chosen})")
        progress.report(self.steps)

    def _end_on_selected(self, csv_file: "ProgressCSV") -> None:
        """The run ends with the best-validated policy: its weights loaded, evaluated as the last row."""
        if self.validate is None or self.selected_step is None or self.eval_env is None:
            return
        path = self.out_dir / "checkpoints" / "selected.pt"
        self.agent.load_state_dict(load_checkpoint(path)["agent"])
        self._sync_rollout_agent()
        row = {"step": self.steps, "seconds": round(self.elapsed, 2), **self._evaluation_row(self.evaluate()),
               "selected_step": self.selected_step, "validation_reward": self.best_validation}
        self.history.append(row)
        self.ended_on_selected = True
        row["last_eval"] = round(self.last_eval(), 5)
        row["best_eval"] = round(max(self.best_eval, row["eval_reward"]), 5)
        csv_file.append(row)
        log.info("the policy of step %d (validation %.4f) kept: eval %.4f", self.selected_step,
                 self.best_validation, row["eval_reward"])

    def last_eval(self) -> float:
        """The headline: mean of the last ``eval_last_k`` evaluations (NaN before the first)."""
        if self.ended_on_selected:
            return float(self.history[-1]["eval_reward"])
        values = [h["eval_reward"] for h in self.history
                  if "eval_reward" in h and h["step"] > 0][-self.config.eval_last_k:]
        return float(np.mean(values)) if values else float("nan")

    # -- the loop ---------------------------------------------------------------------------
    def train(self) -> TrainResult:
        cfg = self.config
        self.progress = progress = Progress(cfg, self.steps, self.elapsed)
        next_eval = (self.steps // cfg.eval_interval + 1) * cfg.eval_interval
        stopped = "total_steps"
        csv_file = ProgressCSV(self.out_dir / "progress.csv")
        if self.history:  # resumed (into a new folder, or in place after a kill): the file holds the checkpoint's rows
            note = csv_file.match_history(self.history)
            if note:
                log.warning("%s", note)
        log.info("PPO %s: %d environment(s) (%s), %d steps per update, learner on %s, rollout on %s",
                 cfg.name, self.num_envs, self.mode, cfg.batch_size,
                 self.device, self.rollout_agent.device)
        if cfg.eval_at_start and self.steps == 0 and self.eval_env is not None and not self.history:
            row = {"step": 0, "seconds": 0.0, **self._evaluation_row(self.evaluate())}
            self._validated(row)
            self.history.append(row)
            csv_file.append(row)
            log.info("untrained policy: eval %.4f%s", row["eval_reward"],
                     f"  validation {row['validation_reward']:.4f}" if "validation_reward" in row else "")
        while self.steps < cfg.total_steps:
            scheduled = self.apply_schedules()
            stats, collect_s, update_s = timed_update(self)
            self.iteration += 1
            elapsed = progress.elapsed()
            terms = mean_terms(self.envs)
            row: dict[str, Any] = {
                "step": self.steps, "seconds": round(elapsed, 2),
                "env_steps_per_s": round(cfg.batch_size / collect_s, 1),
                "steps_per_s": round(cfg.batch_size / update_s, 1),
                **{f"train_{k}": round(v, 5) for k, v in terms.items()},
                **{f"train_{k}": round(v, 5) for k, v in self.episodes.pop().items()},
                **{k: round(v, 6) for k, v in stats.items()},
                "log_std": round(float(self.agent.head.log_std.detach().mean()), 4),
                "learning_rate": float(f"{scheduled['learning_rate']:.4g}"),
                **{f"count_{k}": v for k, v in self.counters().items()},
            }
            time_up = cfg.max_minutes is not None and elapsed > 60 * cfg.max_minutes
            # A run stopped by the clock is evaluated too: its last reward is never left undefined.
            evaluated = self.eval_env is not None and (self.steps >= next_eval or self.steps >= cfg.total_steps
                                                       or time_up)
            if evaluated:
                next_eval = (self.steps // cfg.eval_interval + 1) * cfg.eval_interval
                row.update(self._evaluation_row(self.evaluate()))
                self._validated(row)
            self.history.append(row)
            if evaluated:
                self._record_evaluation(row, elapsed, progress)
            else:
                progress.tick(self.steps)
            csv_file.append(row)
            if self.on_progress is not None:
                self.on_progress(row)
            if evaluated and self.on_eval is not None:
                self.on_eval(self.steps, row["eval_reward"], row)  # may raise optuna.TrialPruned
            if cfg.target_reward is not None and self.last_eval() > cfg.target_reward:
                stopped = "target_reward"
                break
            if time_up:
                stopped = "max_minutes"
                break
        self.elapsed = progress.elapsed()
        self.progress = None
        self.save("last.pt")  # the last policy, to resume from; a validated run then ends on its selected one
        self._end_on_selected(csv_file)
        return TrainResult(self.steps, self.elapsed, self.best_eval, self.last_eval(), self.history, stopped)


def minimised_loss(losses: dict[str, torch.Tensor], critic_only: bool) -> torch.Tensor:
    """What an update minimises of :func:`clipped_ppo_losses`' terms: the critic's alone during the
    critic warm-up, else the surrogate, the critic's and the entropy bonus (when there is one)."""
    if critic_only:
        return losses["loss_critic"]
    total = losses["loss_objective"] + losses["loss_critic"]
    return total + losses["loss_entropy"] if "loss_entropy" in losses else total


def timed_update(trainer) -> tuple[Any, float, float]:
    """One rollout and update of a trainer (its ``collect()``, then its ``learn(batch)``): the
    update's statistics, the seconds of the collection and of both."""
    start = time.perf_counter()
    batch = trainer.collect()
    collected = time.perf_counter()
    stats = trainer.learn(batch)
    return stats, collected - start, time.perf_counter() - start


STAT_KEYS = ("loss_objective", "loss_critic", "kl", "approx_kl", "clip_fraction")
HALF_LOG_2PI = 0.5 * math.log(2 * math.pi)


@dataclass(frozen=True)
class MinibatchData:
    """One update's transitions, flat: normalised observations, actions, their log-probabilities
    under the collecting policy, GAE advantages and value targets."""

    observation: torch.Tensor
    action: torch.Tensor
    log_prob: torch.Tensor
    advantage: torch.Tensor
    value_target: torch.Tensor

    def take(self, index: torch.Tensor) -> "MinibatchData":
        return MinibatchData(self.observation[index], self.action[index], self.log_prob[index],
                             self.advantage[index], self.value_target[index])


def clipped_ppo_losses(agent: Agent, data: MinibatchData, clip_epsilon: float, value_coef: float,
                       entropy_coef: float) -> dict[str, torch.Tensor]:
    """PPO's clipped surrogate, the critic's L2 loss and the entropy bonus of one minibatch: the
    same values and gradients as torchrl's ``ClipPPOLoss`` (advantages standardised per minibatch,
    ratio clipped in log space, critic ``value_coef * mse``; tests/imitation/test_ppo_loss.py
    checks them against it) in plain tensor code."""
    advantage = data.advantage
    if advantage.numel() > 1:  # torchrl: unbiased std, clamped at float32's resolution
        advantage = (advantage - advantage.mean()) / advantage.std().clamp_min(torch.finfo(torch.float).resolution)
    loc, scale = agent.head(data.observation)
    log_scale = scale.log()  # the Normal's density in closed form: no distribution object per minibatch
    log_prob = (-0.5 * ((data.action - loc) / scale).pow(2) - log_scale - HALF_LOG_2PI).sum(-1)
    log_weight = (log_prob - data.log_prob).unsqueeze(-1)
    bound = math.log1p(clip_epsilon)
    low = math.log1p(-clip_epsilon)
    clipped = log_weight.clamp(low, bound)
    gain = torch.minimum(log_weight.exp() * advantage, clipped.exp() * advantage)
    value = agent.critic.module(data.observation)
    losses = {
        "loss_objective": -gain.mean(),
        "loss_critic": value_coef * torch.nn.functional.mse_loss(value, data.value_target),
        "kl": (data.log_prob - log_prob).mean().detach(),
        "approx_kl": ((log_weight.exp() - 1) - log_weight).mean().detach(),  # SB3 1.6's estimator
        "clip_fraction": (clipped != log_weight).float().mean().detach(),
    }
    if entropy_coef > 0:
        losses["loss_entropy"] = -entropy_coef * (0.5 + HALF_LOG_2PI + log_scale).sum(-1).mean()
    return losses


class ProgressCSV:
    """progress.csv: one row per update, appended; the header is the union of the keys seen so
    far (the file is rewritten, atomically, only when a row brings a new key, e.g. the first
    evaluation, or to match a resumed run's history)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.keys: list[str] = []
        if path.exists():
            try:
                with open(path, newline="", encoding="utf-8") as fh:
                    self.keys = list(csv.DictReader(fh).fieldnames or [])
            except (csv.Error, UnicodeDecodeError):
                pass  # damaged: its first rewrite gives it a header again

    def match_history(self, history: list[dict[str, Any]]) -> str | None:
        """Make the file hold exactly ``history``, a checkpoint's rows: after a kill between two
        checkpoints it holds rows the checkpoint does not (the resume trains those steps again:
        they would repeat), and an emptied, torn or damaged file is rebuilt. A file that holds
        them byte for byte is left as it is. Returns the line that says what changed (None:
        nothing, or a new folder's first copy of the curve)."""
        existed = self.path.exists()
        try:
            held = self.path.read_bytes() if existed else b""
        except OSError:
            held = None
        self.keys = list(dict.fromkeys(k for row in history for k in row))
        if held == _csv_text(self.keys, history).encode("utf-8"):
            return None
        steps = [_step(row) for row in self._rows()]
        wanted = [int(row["step"]) for row in history]
        self.keys = []
        self._rewrite(history)
        if not existed:
            return None
        if len(steps) > len(wanted) and steps[:len(wanted)] == wanted:
            return (f"{self.path}: {len(steps) - len(wanted)} row(s) after step {wanted[-1]} (the checkpoint's last) "
                    "removed: this resume trains those steps again")  # fmt: skip
        return (f"{self.path}: rebuilt from the checkpoint's history ({len(wanted)} rows, to step {wanted[-1]}; "
                f"the file held {len(steps)} rows, not those)")  # fmt: skip

    def _rewrite(self, rows: list[dict[str, Any]]) -> None:
        self.keys = list(dict.fromkeys([*self.keys, *(k for row in rows for k in row)]))
        with atomic_path(self.path) as tmp:  # a kill mid-rewrite leaves the old file whole
            tmp.write_bytes(_csv_text(self.keys, rows).encode("utf-8"))

    def _rows(self) -> list[dict[str, Any]]:
        if not self.path.exists():
            return []
        try:
            with open(self.path, newline="", encoding="utf-8") as fh:
                return list(csv.DictReader(fh))
        except (csv.Error, UnicodeDecodeError):  # damaged: a resume rebuilds it (match_history)
            return []

    def append(self, row: dict[str, Any]) -> None:
        if any(k not in self.keys for k in row) or not self.path.exists():
            self._rewrite([*self._rows(), row])  # a new key: the header grows, the file is written again
            return
        with open(self.path, "a", newline="", encoding="utf-8") as fh:
            csv.DictWriter(fh, fieldnames=self.keys, restval="").writerow(row)


def _csv_text(keys: list[str], rows: list[dict[str, Any]]) -> str:
    buffer = io.StringIO(newline="")
    writer = csv.DictWriter(buffer, fieldnames=keys, restval="")
    writer.writeheader()
    writer.writerows(rows)
    return buffer.getvalue()


def _step(row: dict[str, Any]) -> int | None:
    try:
        return int(float(row.get("step")))  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return None


def _duration(seconds: float) -> str:
    seconds = int(round(seconds))
    hours, rest = divmod(seconds, 3600)
    minutes, secs = divmod(rest, 60)
    return f"{hours}h{minutes:02d}m" if hours else f"{minutes}m{secs:02d}s"
