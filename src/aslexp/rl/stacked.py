"""Many PPO runs as one program: letters x seeds (or signs x seeds) trained together, in one process
on one device.

The environments of all runs are one batch (rows ``r*N .. r*N+N-1`` are run ``r``'s, each pinned to
that run's motion: :meth:`~aslexp.envs.batched.BatchedImitationEnv.pin_clips`); their agents are one
stacked module state (``torch.func.stack_module_state``), stepped by ``torch.func.vmap``: one policy
call per control step for every run, one gradient call per minibatch. Each run keeps what makes it
its own: its seed (its initial weights, its sampling noise, its minibatch order, its environments'
streams: each the stream its run alone would draw), its Adam moments and step count, its gradient
clipping, its KL stop, its observation statistics, its evaluations, and its run folder
(progress.csv, checkpoints/last.pt with the agent as :class:`~aslexp.rl.ppo.PPOTrainer` writes it:
beside the run's .hydra/config.yaml, which bench/stacked_letters.py writes, ``policy=RUN_DIR`` reads it). Same seeds give what separate runs give, to float
tolerance (tests/imitation/test_stacked_ppo.py).

The algorithm is :class:`~aslexp.rl.ppo.PPOTrainer`'s, setting for setting (rollout, GAE, the clipped
losses of :func:`~aslexp.rl.ppo.clipped_ppo_losses`, Adam with weight decay, gradient clipping, both
KL stops, schedules, critic warm-up, resuming (:meth:`StackedPPO.restore`: the whole program, or
one run alone through PPOTrainer); not here: coloured noise, worker processes.
"""

from __future__ import annotations

import copy
import logging
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import nn
from torchrl.objectives.value.functional import vec_generalized_advantage_estimate

from aslexp.errors import ConfigError
from aslexp.rl.checkpoint import load_checkpoint, save_checkpoint
from aslexp.rl.evaluate import evaluate_phases
from aslexp.rl.ppo import (STAT_KEYS, EpisodeStats, MinibatchData, PPOConfig, PPOTrainer, Progress, ProgressCSV,
                           clipped_ppo_losses, loss_and_optimizer, make_agent, minimised_loss, resolve_device,
                           timed_update)
from aslexp.rl.vector import worker_seeds

log = logging.getLogger("aslexp.stacked")
ADAM_BETAS, ADAM_EPS = (0.9, 0.999), 1e-8  # torch.optim.Adam's defaults, as PPOTrainer's optimiser


@dataclass
class StackedRun:
    """One run of the program: its seed, its folder, the pool motion its rows imitate, its own
    evaluation environment (None: never evaluated)."""

    seed: int
    out_dir: Path
    clip: int = 0
    eval_env: Any = None


class _AgentCalls(nn.Module):
    """The agent's pieces as one module's ``forward(kind, ...)``, for ``torch.func.functional_call``."""

    def __init__(self, agent: nn.Module) -> None:
        super().__init__()
        self.agent = agent

    def forward(self, kind: str, *args):
        agent = self.agent
        if kind == "normalize":
            return agent.normalizer(args[0])
        if kind == "head":
            return agent.head(args[0])
        if kind == "value":
            return agent.critic.module(args[0])
        return clipped_ppo_losses(agent, MinibatchData(*args[:5]), *args[5:])


class StackedPPO:
    """``runs`` trained together under one ``config`` (``num_envs`` environments each). ``make_env(n)``
    gives a :class:`~aslexp.envs.batched.BatchedImitationEnv` of ``n`` rows over the runs' motions."""

    def __init__(self, make_env: Callable[[int], Any], runs: list[StackedRun], config: PPOConfig) -> None:
        if config.noise_beta > 0 or config.batched_workers or config.vector_env not in ("auto", "batched"):
            raise ConfigError("stacked runs: one batch in this process with white noise (ppo.noise_beta 0, "
                              "ppo.batched_workers 0, ppo.vector_env auto or batched); got noise_beta "
                              f"{config.noise_beta}, batched_workers {config.batched_workers}, "
                              f"vector_env {config.vector_env}")
        if not runs:
            raise ConfigError("stacked runs: no run given")
        torch.set_num_threads(max(1, int(config.torch_threads)))
        self.config, self.runs = config, runs
        self.device = resolve_device(config.device)
        self.num_runs, self.num_envs = len(runs), config.num_envs
        self.envs = make_env(self.num_runs * self.num_envs)
        self.envs.pin_clips(np.repeat([run.clip for run in runs], self.num_envs))
        self.agents, self.generators, self.rngs = [], [], []
        for run in runs:  # each run's weights and streams as its run alone draws them
            torch.manual_seed(run.seed)
            agent = make_agent(self.envs, config).to(self.device)
            if config.log_std_final is not None:  # the noise follows its schedule: no gradient moves it
                agent.head.log_std.requires_grad_(False)
            generator = torch.Generator()
            generator.set_state(torch.get_rng_state())  # the sampling noise continues its run's stream
            self.agents.append(agent)
            self.generators.append(generator)
            self.rngs.append(np.random.default_rng(run.seed))
            run.out_dir = Path(run.out_dir)
            run.out_dir.mkdir(parents=True, exist_ok=True)
        params, buffers = torch.func.stack_module_state(self.agents)
        self.params = {k: v.detach() for k, v in params.items()}
        self.buffers = buffers
        self.trainable = [k for k, p in self.agents[0].named_parameters() if p.requires_grad]
        self.moments = {k: (torch.zeros_like(self.params[k]), torch.zeros_like(self.params[k]))
                        for k in self.trainable}
        self.adam_steps = torch.zeros(self.num_runs, dtype=torch.float64, device=self.device)
        self.calls = _AgentCalls(copy.deepcopy(self.agents[0]).to("meta"))
        self.log_std_key = next(k for k in self.params if k.endswith("log_std"))
        self.steps = self.iteration = 0
        self.elapsed = 0.0  # the program's training seconds so far (every run's)
        self.stopped = "total_steps"  # or max_minutes: what ended the program
        self.learning_rate = config.scheduled(0)[0]  # train() sets it before every update, as PPOTrainer's schedules
        self.histories: list[list[dict[str, Any]]] = [[] for _ in runs]
        self.best_evals = [-float("inf")] * self.num_runs
        self.episodes = [EpisodeStats(self.num_envs) for _ in runs]
        self._obs: np.ndarray | None = None

    # -- the stacked agent -------------------------------------------------------------------------
    def _call(self, kind: str, params: dict, buffers: dict, *args):
        named = ({f"agent.{k}": v for k, v in params.items()}, {f"agent.{k}": v for k, v in buffers.items()})
        return torch.func.functional_call(self.calls, named, (kind, *args))

    def _each(self, kind: str, x: torch.Tensor):
        """``kind`` of every run's agent on its own slice of ``x`` (runs first)."""
        return torch.func.vmap(lambda p, b, v: self._call(kind, p, b, v))(self.params, self.buffers, x)

    def _policy(self, raw: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Every run's (loc, scale) for its rows of raw observations (runs, rows, obs): the normaliser
        and the actor's MLP as batched matrix products. A rollout step asks this once; vmap and
        functional_call would cost a few Python milliseconds a step, the whole step for small batches."""
        norm, b = self.agents[0].normalizer, self.buffers
        x = ((raw.to(torch.float64) - b["normalizer.mean"][:, None])
             / torch.sqrt(b["normalizer.var"][:, None] + norm.eps)).clamp(-norm.clip, norm.clip).to(raw.dtype)
        prefix = self.log_std_key.removesuffix("log_std") + "net."
        for i, layer in enumerate(self.agents[0].head.net):
            if isinstance(layer, nn.Linear):
                weight, bias = self.params[f"{prefix}{i}.weight"], self.params[f"{prefix}{i}.bias"]
                x = torch.baddbmm(bias[:, None], x, weight.transpose(1, 2))
            else:
                x = layer(x)
        return x, self.params[self.log_std_key].exp()[:, None].expand_as(x)

    def _to_env_action(self, sample: torch.Tensor) -> torch.Tensor:
        center = self.buffers["action_center"][:, None]
        half = self.buffers["action_half_range"][:, None]
        if self.config.model.action_mapping == "sb3":
            return torch.clamp(sample, center - half, center + half)
        return center + half * sample

    def agent(self, r: int) -> nn.Module:
        """Run ``r``'s agent as a plain :class:`~aslexp.rl.policy.Agent`, its weights the stacked ones."""
        agent = self.agents[r]
        with torch.no_grad():
            for k, p in agent.named_parameters():
                p.copy_(self.params[k][r])
            for k, b in agent.named_buffers():
                b.copy_(self.buffers[k][r])
        return agent

    # -- rollout -----------------------------------------------------------------------------------
    def collect(self) -> dict[str, torch.Tensor]:
        """One rollout of every run: ``steps_per_env`` steps of its ``num_envs`` rows, as tensors of
        shape (runs, envs, steps, ...)."""
        R, N, n = self.num_runs, self.num_envs, self.config.steps_per_env
        envs = self.envs
        obs_size, act_size = envs.single_observation_space.shape[0], envs.single_action_space.shape[0]
        raw_obs = np.empty((n, R * N, obs_size), np.float32)
        next_raw = np.empty((n, R * N, obs_size), np.float32)
        actions = torch.empty(n, R, N, act_size, device=self.device)
        rewards = np.empty((n, R * N), np.float32)
        terminated = np.empty((n, R * N), bool)
        done = np.empty((n, R * N), bool)
        if self._obs is None:
            seeds = [s for run in self.runs for s in worker_seeds(run.seed, N, self.steps)]
            self._obs, _ = envs.reset(seed=seeds)
        with torch.no_grad():
            for t in range(n):
                raw_obs[t] = self._obs
                x = torch.from_numpy(raw_obs[t]).to(self.device).view(R, N, obs_size)
                loc, scale = self._policy(x)
                eps = torch.stack([torch.randn((N, act_size), generator=g) for g in self.generators]).to(self.device)
                a = loc + scale * eps
                actions[t] = a
                obs, reward, term, trunc, info = envs.step(self._to_env_action(a).reshape(R * N, -1).cpu().numpy())
                next_raw[t] = obs
                ended = term | trunc
                for i in np.flatnonzero(ended):  # same-step reset: obs already starts the next episode
                    next_raw[t, i] = info["final_obs"][i]
                rewards[t], terminated[t], done[t] = reward, term, ended
                for r, stats in enumerate(self.episodes):
                    rows = slice(r * N, (r + 1) * N)
                    stats.step(reward[rows], term[rows], trunc[rows])
                self._obs = obs
        return self._batch(raw_obs, next_raw, actions.permute(1, 2, 0, 3), rewards, terminated, done)

    def _batch(self, raw_obs, next_raw, actions, rewards, terminated, done) -> dict[str, torch.Tensor]:
        """(steps, rows) arrays -> (runs, envs, steps) tensors, observations normalised with the
        statistics the actions were sampled under, then those statistics updated per run."""
        R, N, n = self.num_runs, self.num_envs, raw_obs.shape[0]

        def per_run(values: np.ndarray) -> torch.Tensor:
            moved = np.ascontiguousarray(values.swapaxes(0, 1))  # (rows, steps, ...)
            return torch.from_numpy(moved).to(self.device).reshape(R, N, n, *values.shape[2:])

        raw, next_raw_t = per_run(raw_obs), per_run(next_raw)
        with torch.no_grad():
            observation, next_observation = self._each("normalize", raw), self._each("normalize", next_raw_t)
            loc, scale = self._each("head", observation)
            log_probs = torch.distributions.Normal(loc, scale).log_prob(actions).sum(-1)
            self._update_normalizers(raw.reshape(R, N * n, -1))
        self.steps += n * N
        return {"observation": observation, "next_observation": next_observation, "action": actions,
                "log_prob": log_probs, "reward": per_run(rewards)[..., None], "done": per_run(done)[..., None],
                "terminated": per_run(terminated)[..., None]}

    def _update_normalizers(self, batch: torch.Tensor) -> None:
        """Every run's :class:`~aslexp.rl.policy.RunningNormalizer` update, on its own rows."""
        batch = batch.to(torch.float64)
        mean, var, count = (self.buffers[f"normalizer.{k}"] for k in ("mean", "var", "count"))
        b_mean, b_var, b_count = batch.mean(1), batch.var(1, unbiased=False), batch.shape[1]
        delta = b_mean - mean
        total = count + b_count
        mean += delta * (b_count / total)[:, None]
        m2 = var * count[:, None] + b_var * b_count + delta.pow(2) * (count * b_count / total)[:, None]
        var.copy_(m2 / total[:, None])
        count.copy_(total)

    # -- learning ----------------------------------------------------------------------------------
    def learn(self, batch: dict[str, torch.Tensor]) -> list[dict[str, float]]:
        """GAE and the clipped-surrogate epochs of every run at once; each run's statistics."""
        cfg, R = self.config, self.num_runs
        with torch.no_grad():
            value, next_value = self._each("value", batch["observation"]), self._each("value", batch["next_observation"])
            flat = lambda x: x.reshape(-1, *x.shape[2:])  # noqa: E731  (runs x envs -> rows)
            advantage, value_target = vec_generalized_advantage_estimate(
                cfg.gamma, cfg.gae_lambda, flat(value), flat(next_value), flat(batch["reward"]),
                done=flat(batch["done"]), terminated=flat(batch["terminated"]), time_dim=-2)
        size = batch["action"].shape[1] * batch["action"].shape[2]
        per_run = lambda x: x.reshape(R, size, *x.shape[3:])  # noqa: E731  (runs, transitions, ...)
        data = [per_run(batch["observation"]), per_run(batch["action"]), per_run(batch["log_prob"]),
                advantage.reshape(R, size, 1), value_target.reshape(R, size, 1)]
        limit = None if cfg.target_kl is None else 1.5 * cfg.target_kl
        active = np.ones(R, dtype=bool)  # runs whose epochs go on (a KL stop ends a run's, not the others')
        totals, seen, updates = torch.zeros(R, len(STAT_KEYS)), np.zeros(R, int), np.zeros(R, int)
        grad_step = torch.func.vmap(torch.func.grad(self._loss, has_aux=True), in_dims=(0, 0, 0, 0, 0, 0, 0, 0))
        for _ in range(cfg.epochs):
            if not active.any():
                break
            order = torch.stack([torch.from_numpy(self.rngs[r].permutation(size)) if active[r]
                                 else torch.arange(size) for r in range(R)]).to(self.device)
            for start in range(0, size, cfg.minibatch_size):
                # the gradients of the runs still updating only: a stopped run costs nothing more
                rows = np.flatnonzero(active)
                index = torch.from_numpy(rows).to(self.device)
                params = self._rows(self.params, rows)
                minibatch = (d[index[:, None], order[index, start:start + cfg.minibatch_size]] for d in data)
                grads, stats = grad_step({k: params[k] for k in self.trainable},
                                         {k: v for k, v in params.items() if k not in self.trainable},
                                         self._rows(self.buffers, rows), *minibatch)
                stats = stats.detach().cpu()
                totals[index.cpu()] += stats
                seen[rows] += 1
                kl, approx_kl = stats[:, STAT_KEYS.index("kl")].numpy(), stats[:, STAT_KEYS.index("approx_kl")].numpy()
                step = np.ones(len(rows), dtype=bool)
                if limit is not None and cfg.kl_stop == "sb3":  # before this minibatch's step
                    step = ~(approx_kl > limit)
                self._adam_step({k: g[torch.from_numpy(step)] for k, g in grads.items()} if not step.all() else grads,
                                rows[step])
                updates[rows[step]] += 1
                if limit is not None and cfg.kl_stop == "torchrl":  # after it
                    step &= ~(kl > limit)
                active[rows[~step]] = False
                if not active.any():
                    break
        means = (totals / torch.from_numpy(np.maximum(seen, 1))[:, None]).tolist()
        return [dict(zip(STAT_KEYS, m)) | {"updates": int(u)} for m, u in zip(means, updates)]

    def _loss(self, trainable, fixed, buffers, observation, action, log_prob, advantage, value_target):
        """One run's minibatch loss (what PPOTrainer.learn minimises) and its statistics."""
        cfg = self.config
        losses = self._call("losses", {**trainable, **fixed}, buffers, observation, action, log_prob, advantage,
                            value_target, cfg.clip_epsilon, cfg.value_coef, cfg.entropy_coef)
        total = minimised_loss(losses, critic_only=self.steps <= cfg.critic_warmup_steps)
        return total, torch.stack([losses[k].detach() for k in STAT_KEYS])

    def _adam_step(self, grads: dict[str, torch.Tensor], rows: np.ndarray) -> None:
        """torch.optim.Adam's step (weight decay as L2 in the gradient) after clip_grad_norm_, for the
        runs ``rows`` (``grads``: theirs, in that order); the other runs keep their weights and
        moments. In place on the whole stack when every run steps, else on those rows' copies."""
        cfg, (beta1, beta2) = self.config, ADAM_BETAS
        if len(rows) == 0:
            return
        whole = len(rows) == self.num_runs
        index = torch.from_numpy(rows).to(self.device)
        norms = torch.sqrt(sum(g.reshape(len(g), -1).pow(2).sum(1) for g in grads.values()))
        clip = torch.clamp(cfg.max_grad_norm / (norms + 1e-6), max=1.0)
        self.adam_steps[index] += 1
        steps = self.adam_steps[index]
        step_size = (self.learning_rate / (1 - beta1 ** steps)).to(torch.float32)
        correction2 = torch.sqrt(1 - beta2 ** steps).to(torch.float32)
        with torch.no_grad():
            for k, g in grads.items():
                shape = (-1,) + (1,) * (g.dim() - 1)
                p, (m, v) = self.params[k], self.moments[k]
                if not whole:
                    p, m, v = p[index], m[index], v[index]
                g.mul_(clip.view(shape))
                if cfg.weight_decay:
                    g.add_(p, alpha=cfg.weight_decay)
                m.lerp_(g, 1 - beta1)
                v.mul_(beta2).addcmul_(g, g, value=1 - beta2)
                denom = v.sqrt().div_(correction2.view(shape)).add_(ADAM_EPS)
                p.sub_(m.div(denom).mul_(step_size.view(shape)))
                if not whole:  # the rows' copies back into the stack
                    self.params[k][index], self.moments[k][0][index], self.moments[k][1][index] = p, m, v

    def _rows(self, stacked: dict[str, torch.Tensor], rows: np.ndarray) -> dict[str, torch.Tensor]:
        """The stacked tensors of the runs ``rows`` (all of them: the stack itself, no copy)."""
        if len(rows) == self.num_runs:
            return stacked
        index = torch.from_numpy(rows).to(self.device)
        return {k: v[index] for k, v in stacked.items()}

    def restore(self) -> bool:
        """Continue from the runs' checkpoints/last.pt, written by this program before it stopped
        (a killed job, a time limit): every run's weights, Adam state, streams and history, the
        environments on new episodes (as PPOTrainer's resume). False where no run has one; a set that
        is not one program's at one step is refused."""
        paths = [run.out_dir / "checkpoints" / "last.pt" for run in self.runs]
        present = [p.is_file() for p in paths]
        if not any(present):
            return False
        payloads = [load_checkpoint(p) if here else None for p, here in zip(paths, present)]
        steps = {int(p["steps"]) for p in payloads if p is not None and "stacked" in p}
        if not all(present) or len(steps) != 1 or any("stacked" not in p for p in payloads):
            found = ", ".join(f"{p} ({'steps ' + str(q['steps']) if q else 'none'})" for p, q in zip(paths, payloads))
            raise ConfigError(f"stacked runs: the run folders hold checkpoints of no one program at one step ({found}); "
                              "resume them all together, or start over (overwrite=true, or another folder)")
        with torch.no_grad():
            for r, payload in enumerate(payloads):
                agent = self.agents[r]
                agent.load_state_dict(payload["agent"])
                for k, p in agent.named_parameters():
                    self.params[k][r] = p
                for k, b in agent.named_buffers():
                    self.buffers[k][r] = b
                _, optimizer = loss_and_optimizer(agent, self.config, self.device)
                optimizer.load_state_dict(payload["optimizer"])
                names = {p.data_ptr(): k for k, p in agent.named_parameters()}
                for p, state in optimizer.state.items():
                    m, v = self.moments[names[p.data_ptr()]]
                    m[r], v[r] = state["exp_avg"], state["exp_avg_sq"]
                    self.adam_steps[r] = float(state["step"])
                self.generators[r].set_state(payload["torch_rng"])
                self.rngs[r].bit_generator.state = payload["numpy_rng"]
                self.histories[r] = list(payload["history"])
                self.best_evals[r] = float(payload["best_eval"])
        first = payloads[0]
        self.steps, self.iteration, self.elapsed = int(first["steps"]), int(first["iteration"]), float(first["elapsed"])
        self._obs = None
        log.info("%d runs resumed together at step %d", self.num_runs, self.steps)
        return True

    # -- the program -------------------------------------------------------------------------------
    def train(self) -> list[list[dict[str, Any]]]:
        """Every run to ``total_steps`` (or ``max_minutes``), each evaluated every ``eval_interval``
        steps on its own environment; returns each run's history (its progress.csv rows)."""
        cfg = self.config
        progress = Progress(cfg, self.steps, self.elapsed)
        files = [ProgressCSV(run.out_dir / "progress.csv") for run in self.runs]
        for file, history in zip(files, self.histories):
            if history:  # resumed: each file holds its checkpoint's rows, no later ones
                note = file.match_history(history)
                if note:
                    log.warning("%s", note)
        next_eval = (self.steps // cfg.eval_interval + 1) * cfg.eval_interval
        log.info("%d runs together: %d x %d environments in one batch, %d steps per update per run, on %s",
                 self.num_runs, self.num_runs, self.num_envs, cfg.batch_size, self.device)
        if cfg.eval_at_start and not any(self.histories):
            self._evaluate_all({"step": 0, "seconds": 0.0}, files)
        while self.steps < cfg.total_steps:
            self.learning_rate, log_std = cfg.scheduled(self.steps)
            if log_std is not None:
                self.params[self.log_std_key].fill_(log_std)
            stats, collect_s, update_s = timed_update(self)
            self.iteration += 1
            elapsed = self.elapsed = progress.elapsed()
            time_up = cfg.max_minutes is not None and elapsed > 60 * cfg.max_minutes
            common = {"step": self.steps, "seconds": round(elapsed, 2),
                      "env_steps_per_s": round(self.num_runs * cfg.batch_size / collect_s, 1),
                      "steps_per_s": round(self.num_runs * cfg.batch_size / update_s, 1),
                      "learning_rate": float(f"{self.learning_rate:.4g}")}
            rows = [{**common, **{f"train_{k}": round(v, 5) for k, v in self.episodes[r].pop().items()},
                     **{k: round(v, 6) for k, v in stats[r].items()},
                     "log_std": round(float(self.params[self.log_std_key][r].mean()), 4)} for r in range(self.num_runs)]
            if self.steps >= next_eval or self.steps >= cfg.total_steps or time_up:
                next_eval = (self.steps // cfg.eval_interval + 1) * cfg.eval_interval
                self._evaluate_all(rows, files)
            else:
                for r, row in enumerate(rows):
                    self.histories[r].append(row)
                    files[r].append(row)
            progress.note = f"  {self.num_runs} runs, {common['steps_per_s']:,.0f} steps/s in all"
            progress.tick(self.steps)
            if time_up:
                self.stopped = "max_minutes"
                break
        for r in range(self.num_runs):
            self.save(r)
        return self.histories

    def _evaluate_all(self, rows, files) -> None:
        """Each run's deterministic evaluation on its own environment, its row, its checkpoint."""
        rows = rows if isinstance(rows, list) else [dict(rows) for _ in self.runs]
        for r, (run, row) in enumerate(zip(self.runs, rows)):
            if run.eval_env is not None:
                agent = self.agent(r)
                summary = evaluate_phases(run.eval_env, lambda obs, env: agent.act(obs, deterministic=True),
                                          self.config.eval_steps, self.config.phases)
                row.update(PPOTrainer._evaluation_row(summary))
                self.best_evals[r] = max(self.best_evals[r], row["eval_reward"])
                row["best_eval"] = round(self.best_evals[r], 5)
            self.histories[r].append(row)
            files[r].append(row)
            self.save(r)

    def save(self, r: int) -> Path:
        """Run ``r``'s checkpoints/last.pt as :class:`~aslexp.rl.ppo.PPOTrainer` writes one (its agent,
        its Adam state, its streams): ``resume=`` continues the run alone, re-evaluation reads it."""
        run, agent = self.runs[r], self.agent(r)
        payload = {"agent": agent.state_dict(), "optimizer": self._optimizer_state(r, agent), "steps": self.steps,
                   "iteration": self.iteration, "elapsed": self.elapsed, "best_eval": self.best_evals[r],
                   "history": self.histories[r], "config": asdict(self.config), "best_validation": -float("inf"),
                   "selected_step": None, "seed": run.seed, "torch_rng": self.generators[r].get_state(),
                   "numpy_rng": self.rngs[r].bit_generator.state, "num_envs": self.num_envs,
                   "device": str(self.device),
                   "stacked": {"runs": self.num_runs, "seconds": round(self.elapsed, 2), "stopped": self.stopped}}
        return save_checkpoint(run.out_dir / "checkpoints" / "last.pt", payload)

    def _optimizer_state(self, r: int, agent: nn.Module) -> dict[str, Any]:
        """Run ``r``'s moments and step count as the state_dict of the Adam a PPOTrainer builds."""
        _, optimizer = loss_and_optimizer(agent, self.config, self.device)
        names = {p.data_ptr(): k for k, p in agent.named_parameters()}
        steps = float(self.adam_steps[r])
        for group in optimizer.param_groups:
            group["lr"] = self.learning_rate
            on_device = bool(group.get("fused") or group.get("capturable"))
            for p in group["params"]:
                name = names.get(p.data_ptr())
                if name is None:  # the loss would step a tensor the stack does not hold: never silently
                    raise RuntimeError(f"stacked runs: the optimiser holds a parameter the agent does not ({tuple(p.shape)})")
                if name in self.moments and steps > 0:
                    m, v = self.moments[name]
                    optimizer.state[p] = {"step": torch.tensor(steps, dtype=torch.float32,
                                                               device=p.device if on_device else "cpu"),
                                          "exp_avg": m[r].clone(), "exp_avg_sq": v[r].clone()}
        return optimizer.state_dict()

    def close(self) -> None:
        self.envs.close()
