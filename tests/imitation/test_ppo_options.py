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


def test_schedules_set_the_noise_and_learning_rate_each_update_and_survive_resume(tmp_path, motion_a):
    # log_std_final: the noise is not learned but follows a line from log_std_init; learning_rate_final:
    # the optimiser's rate follows its own. Both are functions of the step, so a resumed run continues them.
    env_cfg = {"action_mode": "residual", "residual_range": 0.2, "episode_steps": 40}
    env = ImitationEnv(motion_a, env=env_cfg)
    eval_env = ImitationEnv(motion_a, env={**env_cfg, "early_termination": {"min_reward": None}})
    config = PPOConfig(**{**TINY, "total_steps": 512, "eval_interval": 512}, log_std_final=-3.0,
                       learning_rate_final=0.0)
    assert config.scheduled(0) == (1e-3, -1.0) and config.scheduled(256) == (5e-4, -2.0)
    assert config.scheduled(10_000) == (0.0, -3.0)  # past the budget: the end values
    first = PPOTrainer(env, eval_env, PPOConfig(**{**TINY, "total_steps": 512, "eval_interval": 512,
                                                   "max_minutes": 1e-9}, log_std_final=-3.0,
                                                learning_rate_final=0.0), tmp_path, seed=0)
    first.train()  # stopped by the clock after one update, at step 128
    assert first.history[-1]["log_std"] == -1.0 and first.history[-1]["learning_rate"] == 1e-3
    second = PPOTrainer(env, eval_env, config, tmp_path, seed=0)
    second.restore(tmp_path / "checkpoints" / "last.pt")
    second.train()
    rows = [(r["step"], r["log_std"], r["learning_rate"]) for r in second.history]
    # Each row is the update that ended at "step"; its schedule was set at step - 128.
    assert rows == [(128, -1.0, 1e-3), (256, -1.5, 7.5e-4), (384, -2.0, 5e-4), (512, -2.5, 2.5e-4)]
    assert not second.agent.head.log_std.requires_grad
    env.close()
    eval_env.close()


def test_without_schedules_the_log_std_is_learned():
    config = PPOConfig(**TINY)
    assert config.scheduled(0) == config.scheduled(256) == (1e-3, None)


def test_a_negative_final_learning_rate_is_refused():
    import pytest

    with pytest.raises(ValueError, match="learning_rate_final must be null or at least 0"):
        PPOConfig(**TINY, learning_rate_final=-1e-4)
