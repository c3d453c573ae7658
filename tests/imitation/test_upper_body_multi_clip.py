"""One policy for several signs: the multi-clip environment and a short PPO run on it."""

from __future__ import annotations

import numpy as np

from aslexp.envs.multi_clip import MultiClipImitationEnv
from aslexp.rl.evaluate import evaluate_clips
from aslexp.rl.ppo import PPOConfig, PPOTrainer

SIGNS = ("00433", "69318")


def make(data_root, **kwargs):
    motions = [data_root / "motions" / "upper_body" / f"{s}.txt" for s in SIGNS]
    return MultiClipImitationEnv(motions, data_root=data_root, env={"episode_steps": 20, "solver_iterations": 10},
                                 **kwargs)


def test_clip_code_and_clip_choice(data_root):
    env = make(data_root, cycle=True)
    assert env.observation_space.shape == (508 + 2,) and env.action_space.shape == (50,)
    names = []
    for _ in range(3):
        obs, info = env.reset(options={"time": 0.0})
        names.append(info["clip"])
        assert obs[-2:].sum() == 1.0 and obs[-2 + env.active] == 1.0
    assert names == ["00433", "69318", "00433"]  # the evaluation env cycles
    obs, reward, terminated, _, info = env.step(env.reference_action(1))
    assert info["clip"] == "00433" and 0 < reward <= 1 and not terminated
    assert env.pop_term_means()["reward"] == reward  # one step so far
    per_clip = evaluate_clips(env, lambda obs, e: e.reference_action(1), steps=10)
    assert set(per_clip) == set(SIGNS) and all(0 < v <= 1 for v in per_clip.values())
    assert per_clip["00433"] != per_clip["69318"]
    env.close()


def test_short_ppo_run_on_two_signs(tmp_path, data_root):
    env, eval_env = make(data_root), make(data_root, cycle=True)
    config = PPOConfig(hidden_sizes=(32, 32), learning_rate=1e-3, steps_per_rollout=128, minibatch_size=64,
                       epochs=2, log_std_init=-1.0, eval_interval=128, eval_steps=10, total_steps=256,
                       target_kl=None)
    result = PPOTrainer(env, eval_env, config, tmp_path, seed=0).train()
    assert result.steps == 256 and np.isfinite(result.best_eval)
    row = result.history[-1]
    assert "train_pose_hands" in row and row["count_episodes"] >= 2
    env.close()
    eval_env.close()
