"""PPO for imitation, CleanRL-style: collect a rollout, GAE, clipped-surrogate epochs, repeat.

The rollout loop steps one gymnasium environment directly (on two cores torchrl's collectors
and ParallelEnv cost more than they give); the rollout becomes a TensorDict and the learning
side is torchrl's: :class:`~torchrl.objectives.value.GAE` and
:class:`~torchrl.objectives.ClipPPOLoss`. Every ``eval_interval`` environment steps the policy
is evaluated deterministically (``on_eval`` is called: the job reports to the sweep there) and
a checkpoint is written; ``resume_from`` continues a run from its checkpoint.
"""

from __future__ import annotations

import csv
import logging
import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tensordict import TensorDict
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.value import GAE

from aslexp.rl.checkpoint import load_checkpoint, save_checkpoint
from aslexp.rl.policy import Agent, ModelSpec

log = logging.getLogger("aslexp.ppo")
LOG_PROB = "action_log_prob"


@dataclass(frozen=True)
class PPOConfig:
    """``conf/ppo/*.yaml`` as plain values."""

    name: str = "custom"
    hidden_sizes: tuple[int, ...] = (1024, 1024)
    activation: str = "relu"
    learning_rate: float = 3e-4
    steps_per_rollout: int = 4096
    minibatch_size: int = 256
    epochs: int = 3
    gamma: float = 0.95
    gae_lambda: float = 0.95
    clip_epsilon: float = 0.2
    entropy_coef: float = 0.0
    value_coef: float = 5.0
    max_grad_norm: float = 100.0
    target_kl: float | None = 0.05
    log_std_init: float = -3.0
    ortho_init: bool = True
    weight_decay: float = 1e-5
    total_steps: int = 50_000_000
    eval_interval: int = 50_000
    eval_steps: int = 300
    max_minutes: float | None = None
    target_reward: float | None = None  # stop once the evaluation reward exceeds this
    # Environment steps during which only the critic learns: a policy that starts near a good
    # controller (residual actions) is otherwise moved by advantages that are mostly critic error.
    critic_warmup_steps: int = 0
    torch_threads: int = 1

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> "PPOConfig":
        unknown = set(values) - set(cls.__dataclass_fields__)
        if unknown:
            raise ValueError(f"ppo config: unknown keys {sorted(unknown)}")
        values = dict(values)
        if "hidden_sizes" in values:
            values["hidden_sizes"] = tuple(int(h) for h in values["hidden_sizes"])
        return cls(**values)

    @property
    def model(self) -> ModelSpec:
        return ModelSpec(self.hidden_sizes, self.activation, self.ortho_init, self.log_std_init)


@dataclass
class TrainResult:
    steps: int
    seconds: float
    best_eval: float
    last_eval: float
    history: list[dict[str, Any]] = field(default_factory=list)
    stopped: str = "total_steps"  # total_steps | max_minutes | target_reward


def make_agent(env, config: PPOConfig) -> Agent:
    low, high = env.action_space.low.astype(np.float64), env.action_space.high.astype(np.float64)
    return Agent(env.observation_space.shape[0], env.action_space.shape[0], config.model,
                 (low + high) / 2, (high - low) / 2)


class PPOTrainer:
    """Owns the agent, the optimiser, the loss and the training state of one run."""

    def __init__(self, env, eval_env, config: PPOConfig, out_dir: str | Path, seed: int = 0,
                 on_eval: Callable[[int, float, dict[str, Any]], None] | None = None) -> None:
        torch.set_num_threads(max(1, int(config.torch_threads)))
        self.env, self.eval_env, self.config = env, eval_env, config
        self.out_dir = Path(out_dir)
        self.out_dir.mkdir(parents=True, exist_ok=True)
        self.on_eval = on_eval
        torch.manual_seed(seed)
        self.rng = np.random.default_rng(seed)
        self.seed = seed
        self.agent = make_agent(env, config)
        self.loss = ClipPPOLoss(
            self.agent.actor, self.agent.critic, clip_epsilon=config.clip_epsilon,
            entropy_bonus=config.entropy_coef > 0, entropy_coeff=config.entropy_coef or None,
            critic_coeff=config.value_coef, loss_critic_type="l2", normalize_advantage=True,
        )
        self.loss.set_keys(sample_log_prob=LOG_PROB)
        self.gae = GAE(gamma=config.gamma, lmbda=config.gae_lambda, value_network=self.agent.critic,
                       average_gae=False)
        self.optimizer = torch.optim.Adam(self.loss.parameters(), lr=config.learning_rate,
                                          weight_decay=config.weight_decay)
        self.steps = 0
        self.iteration = 0
        self.elapsed = 0.0  # training seconds before this process (resume)
        self.best_eval = -math.inf
        self.history: list[dict[str, Any]] = []
        self._obs = None

    # -- checkpoints ----------------------------------------------------------------------
    def state(self) -> dict[str, Any]:
        return {
            "agent": self.agent.state_dict(), "optimizer": self.optimizer.state_dict(),
            "steps": self.steps, "iteration": self.iteration, "elapsed": self.elapsed,
            "best_eval": self.best_eval, "history": self.history, "config": asdict(self.config),
            "seed": self.seed, "torch_rng": torch.get_rng_state(), "numpy_rng": self.rng.bit_generator.state,
        }

    def save(self, name: str = "last.pt") -> Path:
        return save_checkpoint(self.out_dir / "checkpoints" / name, self.state())

    def restore(self, path: str | Path) -> None:
        payload = load_checkpoint(path)
        try:
            self.agent.load_state_dict(payload["agent"])
            self.optimizer.load_state_dict(payload["optimizer"])
        except (KeyError, RuntimeError, ValueError) as exc:
            raise ValueError(f"checkpoint {path} does not fit this model/config: {exc}") from exc
        self.steps, self.iteration = int(payload["steps"]), int(payload["iteration"])
        self.elapsed, self.best_eval = float(payload["elapsed"]), float(payload["best_eval"])
        self.history = list(payload["history"])
        torch.set_rng_state(payload["torch_rng"])
        self.rng.bit_generator.state = payload["numpy_rng"]
        log.info("resumed from %s at step %d", path, self.steps)

    # -- rollout ----------------------------------------------------------------------------
    def collect(self) -> TensorDict:
        """One rollout of ``steps_per_rollout`` steps as a (T,) TensorDict of normalised observations."""
        n, env, agent = self.config.steps_per_rollout, self.env, self.agent
        obs_size, act_size = env.observation_space.shape[0], env.action_space.shape[0]
        raw_obs = np.empty((n + 1, obs_size), np.float32)
        actions = torch.empty(n, act_size)
        rewards = np.empty(n, np.float32)
        terminated = np.zeros(n, bool)
        done = np.zeros(n, bool)
        next_raw = np.empty((n, obs_size), np.float32)
        head = agent.actor.module[0].module
        if self._obs is None:
            self._obs, _ = env.reset(seed=int(self.rng.integers(2**31)))
        with torch.no_grad():
            for t in range(n):
                raw_obs[t] = self._obs
                loc, scale = head(agent.normalizer(torch.from_numpy(self._obs)))
                a = loc + scale * torch.randn_like(loc)
                actions[t] = a
                obs, reward, term, trunc, _ = env.step(agent.to_env_action(a).numpy())
                rewards[t], terminated[t], done[t] = reward, term, term or trunc
                next_raw[t] = obs
                self._obs = env.reset()[0] if (term or trunc) else obs
        # Normalise with the statistics the actions were taken under, then update them.
        norm = agent.normalizer
        observation = norm(torch.from_numpy(raw_obs[:n]))
        next_observation = norm(torch.from_numpy(next_raw))
        with torch.no_grad():  # same parameters as during the rollout: one batched pass
            loc, scale = head(observation)
            log_probs = torch.distributions.Normal(loc, scale).log_prob(actions).sum(-1)
        norm.update(torch.from_numpy(raw_obs[:n]))
        self.steps += n
        return TensorDict({
            "observation": observation, "action": actions, LOG_PROB: log_probs,
            "next": {"observation": next_observation,
                     "reward": torch.from_numpy(rewards).unsqueeze(-1),
                     "done": torch.from_numpy(done).unsqueeze(-1),
                     "terminated": torch.from_numpy(terminated).unsqueeze(-1)},
        }, batch_size=[n])

    # -- learning ---------------------------------------------------------------------------
    def learn(self, batch: TensorDict) -> dict[str, float]:
        cfg = self.config
        with torch.no_grad():
            self.gae(batch)
        stats = {"loss_objective": 0.0, "loss_critic": 0.0, "kl": 0.0, "clip_fraction": 0.0}
        updates = 0
        stop = False
        for _ in range(cfg.epochs):
            order = torch.from_numpy(self.rng.permutation(len(batch)))
            for start in range(0, len(batch), cfg.minibatch_size):
                minibatch = batch[order[start:start + cfg.minibatch_size]]
                losses = self.loss(minibatch)
                if self.steps <= cfg.critic_warmup_steps:
                    total = losses["loss_critic"]
                else:
                    total = losses["loss_objective"] + losses["loss_critic"]
                    if "loss_entropy" in losses.keys():
                        total = total + losses["loss_entropy"]
                self.optimizer.zero_grad()
                total.backward()
                torch.nn.utils.clip_grad_norm_(self.loss.parameters(), cfg.max_grad_norm)
                self.optimizer.step()
                kl = float(losses.get("kl_approx", torch.tensor(0.0)).detach())
                stats["loss_objective"] += float(losses["loss_objective"].detach())
                stats["loss_critic"] += float(losses["loss_critic"].detach())
                stats["kl"] += kl
                stats["clip_fraction"] += float(losses.get("clip_fraction", torch.tensor(0.0)).detach())
                updates += 1
                if cfg.target_kl is not None and kl > 1.5 * cfg.target_kl:
                    stop = True  # as Stable-Baselines3: stop the epochs when the policy moved too far
                    break
            if stop:
                break
        return {k: v / max(updates, 1) for k, v in stats.items()} | {"updates": updates}

    def evaluate(self) -> tuple[float, dict[str, float]]:
        from aslexp.rl.evaluate import evaluate

        result = evaluate(self.eval_env, lambda obs, env: self.agent.act(obs, deterministic=True),
                          self.config.eval_steps)
        return result.mean_reward, result.terms

    # -- the loop ---------------------------------------------------------------------------
    def train(self) -> TrainResult:
        cfg = self.config
        start, elapsed_before = time.perf_counter(), self.elapsed
        next_eval = (self.steps // cfg.eval_interval + 1) * cfg.eval_interval
        stopped = "total_steps"
        # The last row may be a rollout without an evaluation (a run stopped by max_minutes).
        last_eval = next((h["eval_reward"] for h in reversed(self.history) if "eval_reward" in h), float("nan"))
        progress_path = self.out_dir / "progress.csv"
        while self.steps < cfg.total_steps:
            t0 = time.perf_counter()
            batch = self.collect()
            t1 = time.perf_counter()
            stats = self.learn(batch)
            t2 = time.perf_counter()
            self.iteration += 1
            elapsed = elapsed_before + time.perf_counter() - start
            terms = self.env.pop_term_means() if hasattr(self.env, "pop_term_means") else {}
            row: dict[str, Any] = {
                "step": self.steps, "seconds": round(elapsed, 2),
                "env_steps_per_s": round(cfg.steps_per_rollout / (t1 - t0), 1),
                "steps_per_s": round(cfg.steps_per_rollout / (t2 - t0), 1),
                **{f"train_{k}": round(v, 5) for k, v in terms.items()},
                **{k: round(v, 6) for k, v in stats.items()},
                "log_std": round(float(self.agent.actor.module[0].module.log_std.detach().mean()), 4),
            }
            counters = getattr(self.env, "counters", {})
            row.update({f"count_{k}": v for k, v in counters.items()})
            time_up = cfg.max_minutes is not None and elapsed > 60 * cfg.max_minutes
            # A run stopped by the clock is evaluated too: its best reward is never left undefined.
            if self.steps >= next_eval or self.steps >= cfg.total_steps or time_up:
                next_eval = (self.steps // cfg.eval_interval + 1) * cfg.eval_interval
                last_eval, eval_terms = self.evaluate()
                row["eval_reward"] = round(last_eval, 5)
                row.update({f"eval_{k}": round(v, 5) for k, v in eval_terms.items()})
                self.history.append(row)
                self.elapsed = elapsed
                if last_eval > self.best_eval:
                    self.best_eval = last_eval
                    self.save("best.pt")
                self.save("last.pt")
                rate = self.steps / max(elapsed, 1e-9)
                eta = (cfg.total_steps - self.steps) / max(rate, 1e-9)
                log.info("step %d  eval %.4f (best %.4f)  train %.4f  %.0f steps/s  ETA %.0f s",
                         self.steps, last_eval, self.best_eval, terms.get("reward", float("nan")), rate, eta)
                if self.on_eval is not None:
                    self.on_eval(self.steps, last_eval, row)  # may raise optuna.TrialPruned
            else:
                self.history.append(row)
            _append_csv(progress_path, row)
            if cfg.target_reward is not None and last_eval > cfg.target_reward:
                stopped = "target_reward"
                break
            if time_up:
                stopped = "max_minutes"
                break
        self.elapsed = elapsed_before + time.perf_counter() - start
        self.save("last.pt")
        return TrainResult(self.steps, self.elapsed, self.best_eval, last_eval, self.history, stopped)


def _append_csv(path: Path, row: dict[str, Any]) -> None:
    """Append a row; the header is the union of keys seen so far (rewritten when it grows)."""
    rows = []
    if path.exists():
        with open(path, newline="", encoding="utf-8") as fh:
            rows = list(csv.DictReader(fh))
    keys = list(dict.fromkeys([k for r in rows for k in r] + list(row)))
    rows.append({k: row.get(k, "") for k in row})
    with open(path, "w", newline="", encoding="utf-8") as fh:
        writer = csv.DictWriter(fh, fieldnames=keys)
        writer.writeheader()
        for r in rows:
            writer.writerow({k: r.get(k, "") for k in keys})
