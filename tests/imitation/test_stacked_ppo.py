"""Many runs as one program (aslexp.rl.stacked): two runs trained together, their environments one
batch and their policies one stacked network, give what the same two runs give alone, to float
tolerance, over their first updates; each run writes its own folder."""

from __future__ import annotations

import functools

import numpy as np
import pytest
import torch

from aslexp.envs.batched import BatchedImitationEnv
from aslexp.rl.checkpoint import load_checkpoint
from aslexp.rl.ppo import PPOConfig, PPOTrainer
from aslexp.rl.stacked import StackedPPO, StackedRun


# Two updates of 2 environments x 32 steps, minibatches of 32 over 2 epochs; short episodes that
# end inside a rollout (truncated at 12 steps) so that resets and bootstrapping are compared too.
TINY = dict(hidden_sizes=(16, 16), learning_rate=1e-3, steps_per_rollout=64, minibatch_size=32, epochs=2,
            log_std_init=-1.0, weight_decay=1e-5, eval_interval=64, eval_steps=10, eval_episodes=2,
            total_steps=128, num_envs=2, vector_env="batched", device="cpu", max_grad_norm=0.5)
ENV = {"episode_steps": 12}


def _factory(motions):
    return functools.partial(BatchedImitationEnv, motion=motions[0], motions=list(motions), engine="mujoco",
                             env=ENV)


def _alone(motion, seed, config, out_dir):
    """The run by itself: PPOTrainer on a batch of its own motion."""
    trainer = PPOTrainer(_factory([motion]), None, config, out_dir, seed=seed)
    try:
        stats = []
        for _ in range(config.total_steps // config.batch_size):
            trainer.apply_schedules()
            stats.append(trainer.learn(trainer.collect()))
        weights = {k: v.detach().clone() for k, v in trainer.agent.state_dict().items()}
        return weights, stats, trainer.optimizer.state_dict()
    finally:
        trainer.close()


@pytest.mark.parametrize("kl", [None, "sb3", "torchrl"])
def test_two_runs_together_match_the_same_runs_alone(tmp_path, data_root, kl):
    motions = [data_root / "motions" / "hand" / f"{letter}.txt" for letter in "AB"]
    # with a KL stop that ends the runs' epochs early (and not at the same minibatch: each run its own)
    config = PPOConfig(**TINY, **({"target_kl": 0.002, "kl_stop": kl} if kl else {"target_kl": None}))
    runs = [StackedRun(seed=3, out_dir=tmp_path / "A", clip=0), StackedRun(seed=8, out_dir=tmp_path / "B", clip=1)]
    together = StackedPPO(_factory(motions), runs, config)
    try:
        stats_together = []
        for _ in range(config.total_steps // config.batch_size):
            together.learning_rate = config.scheduled(together.steps)[0]
            stats_together.append(together.learn(together.collect()))
        for r, (motion, run) in enumerate(zip(motions, runs)):
            weights, stats, adam = _alone(motion, run.seed, config, tmp_path / f"alone{r}")
            mine = together.agent(r).state_dict()
            # its checkpoint's optimiser is the Adam state the run alone holds (what resume= reads)
            ours = together._optimizer_state(r, together.agent(r))
            assert sorted(ours["state"]) == sorted(adam["state"])
            for index, state in adam["state"].items():
                assert float(ours["state"][index]["step"]) == float(state["step"])
                for key in ("exp_avg", "exp_avg_sq"):
                    assert torch.allclose(ours["state"][index][key], state[key], atol=1e-6, rtol=1e-3), (r, index, key)
            assert [s["updates"] for s in stats] == [s[r]["updates"] for s in stats_together]
            for key, value in weights.items():
                assert torch.allclose(mine[key], value, atol=2e-5, rtol=1e-4), (r, key, (mine[key] - value).abs().max())
            for update, alone in enumerate(stats):
                for key in ("loss_objective", "loss_critic", "approx_kl"):
                    assert stats_together[update][r][key] == pytest.approx(alone[key], rel=1e-3, abs=1e-6)
        if kl:  # the KL stop acted: not every minibatch was applied
            assert any(s[r]["updates"] < 4 for s in stats_together for r in range(2))
    finally:
        together.close()


def test_each_run_of_the_program_writes_its_own_folder(tmp_path, data_root):
    motions = [data_root / "motions" / "hand" / f"{letter}.txt" for letter in "AB"]
    from aslexp.envs.imitation import ImitationEnv

    evals = [ImitationEnv(m, engine="mujoco", env=ENV) for m in motions]
    runs = [StackedRun(seed=s, out_dir=tmp_path / f"run{s}", clip=c, eval_env=e)
            for s, c, e in ((0, 0, evals[0]), (1, 1, evals[1]), (2, 0, evals[0]))]
    together = StackedPPO(_factory(motions), runs, PPOConfig(**{**TINY, "eval_at_start": True}))
    try:
        histories = together.train()
    finally:
        together.close()
        for e in evals:
            e.close()
    assert [len(h) for h in histories] == [3, 3, 3]  # the untrained policy, then two evaluated updates
    for run, history in zip(runs, histories):
        csv = (run.out_dir / "progress.csv").read_text().splitlines()
        assert len(csv) == 4 and "eval_reward" in csv[0]
        assert all(np.isfinite(row["eval_reward"]) for row in history)
        checkpoint = load_checkpoint(run.out_dir / "checkpoints" / "last.pt")
        assert checkpoint["seed"] == run.seed and checkpoint["steps"] == 128
    # the two seeds on motion A learn apart; their untrained evaluations differ by their initial weights
    a0, a2 = (load_checkpoint(r.out_dir / "checkpoints" / "last.pt")["agent"] for r in (runs[0], runs[2]))
    assert not torch.allclose(a0["critic.module.0.weight"], a2["critic.module.0.weight"])
    # a run of the program continues alone: PPOTrainer resumes its checkpoint, one update more
    alone = PPOTrainer(_factory(motions[:1]), None, PPOConfig(**{**TINY, "total_steps": 192}), tmp_path / "alone", seed=0)
    try:
        alone.restore(runs[0].out_dir / "checkpoints" / "last.pt")
        assert alone.steps == 128 and len(alone.history) == 3
        result = alone.train()
    finally:
        alone.close()
    assert result.steps == 192 and len(result.history) == 4


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU (torch finds none)")
def test_two_runs_together_on_a_gpu_match_them_on_the_cpu(tmp_path, data_root):
    motions = [data_root / "motions" / "hand" / f"{letter}.txt" for letter in "AB"]
    weights = {}
    for device in ("cpu", "cuda"):
        runs = [StackedRun(seed=3, out_dir=tmp_path / device / "A", clip=0),
                StackedRun(seed=8, out_dir=tmp_path / device / "B", clip=1)]
        config = PPOConfig(**{**TINY, "device": device}, target_kl=None)
        together = StackedPPO(_factory(motions), runs, config)
        try:
            for _ in range(config.total_steps // config.batch_size):
                together.learning_rate = config.scheduled(together.steps)[0]
                together.learn(together.collect())
            weights[device] = [{k: v.cpu() for k, v in together.agent(r).state_dict().items()} for r in range(2)]
        finally:
            together.close()
    for cpu, gpu in zip(weights["cpu"], weights["cuda"]):
        for key in cpu:
            assert torch.allclose(cpu[key], gpu[key], atol=1e-3, rtol=1e-3), key
