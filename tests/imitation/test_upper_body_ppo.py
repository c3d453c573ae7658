"""A short PPO run on the upper body improves on its start (torchrl, the hand's trainer)."""

from __future__ import annotations

from aslexp.compose import deep_merge, group as load_group_file
from aslexp.envs.upper_body import UpperBodyImitationEnv
from aslexp.rl.ppo import PPOConfig, PPOTrainer

TINY = dict(hidden_sizes=(64, 64), learning_rate=3e-3, steps_per_rollout=384, minibatch_size=128, epochs=10,
            log_std_init=-0.5, weight_decay=0.0, eval_interval=384, eval_steps=30, target_kl=None,
            total_steps=1536, eval_episodes=1)  # one evaluation episode (from phase 0): a quick test

# From a mid-range start every joint is far off and the default k-factors leave the product flat
# at ~0; gentler scales on the averaged reward give a short run a gradient (the reward is config,
# like the hand's test; measured with the averaged errors, so it names that reward).
GENTLE = deep_merge(load_group_file("reward", "upper_body_averaged"),
                    {"terms": {"pose_body": {"scale": 0.2}, "pose_hands": {"scale": 0.2},
                               "velocity_body": {"scale": 0.01}, "velocity_hands": {"scale": 0.01},
                               "end_effector": {"scale": 4.0}}})


def test_short_ppo_run_on_a_sign_improves(tmp_path, data_root):
    motion = data_root / "motions" / "upper_body" / "00433.txt"
    cfg = {"episode_steps": 30, "solver_iterations": 10}  # 10: a quick test, not the default physics
    env = UpperBodyImitationEnv(motion, env=cfg, reward=GENTLE, data_root=data_root)
    eval_env = UpperBodyImitationEnv(motion, env={**cfg, "reference_state_init": False}, reward=GENTLE,
                                     data_root=data_root)
    trainer = PPOTrainer(env, eval_env, PPOConfig(**TINY), tmp_path, seed=0)
    start = trainer.evaluate().mean_reward
    result = trainer.train()
    assert result.steps == 1536
    # Measured: 0.013 -> 0.090 (seed 0, single thread; PyBullet and CPU torch are deterministic).
    assert result.best_eval > start + 0.02, (start, result.best_eval)
    row = result.history[-1]
    assert "train_pose_hands" in row and "eval_velocity_body" in row
    env.close()
    eval_env.close()
