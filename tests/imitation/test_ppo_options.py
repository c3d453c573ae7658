"""PPO options added for residual learning on a tracking controller."""

from __future__ import annotations

import torch

from aslexp.envs.imitation import ImitationEnv
from aslexp.rl.ppo import PPOConfig, PPOTrainer

TINY = dict(hidden_sizes=(32, 32), learning_rate=1e-3, steps_per_rollout=128, minibatch_size=64, epochs=2,
            log_std_init=-1.0, weight_decay=0.0, eval_interval=256, eval_steps=10, target_kl=None,
            total_steps=256)


def test_critic_warmup_trains_only_the_critic(tmp_path, motion_a):
    env_cfg = {"action_mode": "residual", "residual_range": 0.2, "episode_steps": 40}
    env = ImitationEnv(motion_a, env=env_cfg, controller="reference_velocity")
    eval_env = ImitationEnv(motion_a, env={**env_cfg, "early_termination": {"min_reward": None}},
                            controller="reference_velocity")
    trainer = PPOTrainer(env, eval_env, PPOConfig(**TINY, critic_warmup_steps=256), tmp_path, seed=0)
    actor = [p.detach().clone() for p in trainer.agent.actor.parameters()]
    critic = [p.detach().clone() for p in trainer.agent.critic.parameters()]
    trainer.train()
    assert all(torch.equal(a, b) for a, b in zip(actor, trainer.agent.actor.parameters()))
    assert not all(torch.equal(a, b) for a, b in zip(critic, trainer.agent.critic.parameters()))
    env.close()
    eval_env.close()


def test_a_run_stopped_by_the_clock_is_evaluated_and_resumes(tmp_path, motion_a):
    # max_minutes can stop a run between evaluations: it is evaluated at the stop, so its best
    # reward is defined, and a resumed run continues from there.
    env_cfg = {"action_mode": "residual", "residual_range": 0.2, "episode_steps": 40}
    env = ImitationEnv(motion_a, env=env_cfg)
    eval_env = ImitationEnv(motion_a, env={**env_cfg, "early_termination": {"min_reward": None}})
    first = PPOTrainer(env, eval_env, PPOConfig(**{**TINY, "max_minutes": 1e-9}), tmp_path, seed=0)
    result = first.train()
    assert result.stopped == "max_minutes" and first.steps == 128
    assert "eval_reward" in first.history[-1] and 0.0 < result.best_eval <= 1.0
    second = PPOTrainer(env, eval_env, PPOConfig(**TINY), tmp_path, seed=0)
    second.restore(tmp_path / "checkpoints" / "last.pt")
    result = second.train()
    assert result.steps == 256 and "eval_reward" in result.history[-1]
    env.close()
    eval_env.close()
