"""The learner's minibatch loss is torchrl's ClipPPOLoss, written as plain tensor code for speed:
the same values and the same gradients on a real rollout of the hand, with and without the entropy
bonus, and with clipping active (a policy moved after the rollout)."""

from __future__ import annotations

import functools

import pytest
import torch
from torchrl.objectives import ClipPPOLoss

from aslexp.envs.batched import BatchedImitationEnv
from aslexp.rl.ppo import LOG_PROB, MinibatchData, PPOConfig, PPOTrainer, clipped_ppo_losses


@pytest.fixture(scope="module")
def rollout(tmp_path_factory):
    config = PPOConfig(hidden_sizes=(32, 32), num_envs=4, vector_env="batched", steps_per_rollout=256,
                       minibatch_size=64, device="cpu", eval_interval=10**9, total_steps=256)
    make = functools.partial(BatchedImitationEnv, motion="motions/hand/A.txt", engine="mujoco")
    trainer = PPOTrainer(make, None, config, tmp_path_factory.mktemp("ppo"), seed=3)
    batch = trainer.collect()
    with torch.no_grad():
        trainer.gae(batch)
    yield trainer, batch.reshape(-1)[:128]
    trainer.close()


@pytest.mark.parametrize("entropy_coef", [0.0, 0.01])
def test_plain_loss_equals_torchrl_clip_ppo_loss(rollout, entropy_coef):
    trainer, minibatch = rollout
    agent = trainer.agent
    torch.manual_seed(0)
    with torch.no_grad():  # move the policy so that some ratios leave the clip range
        for p in agent.head.net.parameters():
            p.add_(0.004 * torch.randn_like(p))
    reference = ClipPPOLoss(agent.actor, agent.critic, clip_epsilon=0.2, entropy_bonus=entropy_coef > 0,
                            entropy_coeff=entropy_coef or None, critic_coeff=5.0, loss_critic_type="l2",
                            normalize_advantage=True)
    reference.set_keys(sample_log_prob=LOG_PROB)
    params = [p for p in agent.parameters() if p.requires_grad]

    def grads(losses):
        total = sum(v for k, v in losses.items() if k.startswith("loss_"))
        return torch.autograd.grad(total, params, allow_unused=True)

    expected = reference(minibatch.clone())
    data = MinibatchData(minibatch["observation"], minibatch["action"], minibatch[LOG_PROB],
                         minibatch["advantage"], minibatch["value_target"])
    ours = clipped_ppo_losses(agent, data, 0.2, 5.0, entropy_coef)
    assert 0.0 < float(ours["clip_fraction"]) < 1.0  # clipping is exercised
    for key, theirs in (("loss_objective", "loss_objective"), ("loss_critic", "loss_critic"),
                        ("kl", "kl_approx"), ("clip_fraction", "clip_fraction")):
        torch.testing.assert_close(ours[key], expected[theirs].squeeze(), rtol=1e-5, atol=1e-6)
    if entropy_coef:
        torch.testing.assert_close(ours["loss_entropy"], expected["loss_entropy"].squeeze(), rtol=1e-5, atol=1e-6)
    expected_losses = {k: expected[k] for k in expected.keys() if k.startswith("loss_")}
    for a, b in zip(grads(ours), grads(expected_losses)):
        if a is None or b is None:
            assert a is None and b is None
        else:
            # atol 1e-5: float32 sums in another order (another CPU's kernels) move a near-zero entry by ~1e-6
            torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-5)


def test_optimizer_steps_the_modules_own_parameters(rollout):
    """The optimiser holds the loss module's parameters: they must be the agent's (the plain loss
    computes gradients on the agent's modules)."""
    trainer, _ = rollout
    ours = {id(p) for p in trainer.agent.parameters()}
    held = {id(p) for group in trainer.optimizer.param_groups for p in group["params"]}
    assert held <= ours and len(held) >= 4


def test_sb3_approx_kl_is_its_estimator(rollout):
    """approx_kl is Stable-Baselines3 1.6's mean((r - 1) - log r), r = pi / pi_old, from the policy's
    own Normal (torch.distributions), and never negative."""
    trainer, minibatch = rollout
    agent = trainer.agent
    data = MinibatchData(minibatch["observation"], minibatch["action"], minibatch[LOG_PROB],
                         minibatch["advantage"], minibatch["value_target"])
    with torch.no_grad():
        for p in agent.head.net.parameters():
            p.add_(0.002 * torch.randn_like(p, generator=torch.Generator().manual_seed(1)))
        ours = clipped_ppo_losses(agent, data, 0.2, 5.0, 0.0)
        loc, scale = agent.head(data.observation)
        log_ratio = torch.distributions.Normal(loc, scale).log_prob(data.action).sum(-1) - data.log_prob
        expected = ((log_ratio.exp() - 1) - log_ratio).mean()
    torch.testing.assert_close(ours["approx_kl"], expected, rtol=1e-5, atol=1e-7)
    assert float(ours["approx_kl"]) >= 0


@pytest.mark.parametrize("kl_stop, steps", [("sb3", 0), ("torchrl", 1)])
def test_the_kl_stop_acts_before_the_step_as_sb3_or_after_it_as_torchrl(tmp_path, kl_stop, steps):
    """With a limit every minibatch passes, SB3 (the authors' library) applies no step of the update;
    torchrl's reading applies the first and stops."""
    config = PPOConfig(hidden_sizes=(32, 32), num_envs=4, vector_env="batched", steps_per_rollout=256,
                       minibatch_size=64, device="cpu", eval_interval=10**9, total_steps=256,
                       target_kl=1e-12, kl_stop=kl_stop)
    make = functools.partial(BatchedImitationEnv, motion="motions/hand/A.txt", engine="mujoco")
    trainer = PPOTrainer(make, None, config, tmp_path, seed=3)
    try:
        batch = trainer.collect()
        with torch.no_grad():  # the policy that collected, moved: every minibatch's KL is above the limit
            for p in trainer.agent.head.net.parameters():
                p.add_(0.004 * torch.randn_like(p, generator=torch.Generator().manual_seed(2)))
        before = [p.detach().clone() for p in trainer.agent.parameters()]
        stats = trainer.learn(batch)
        moved = any(not torch.equal(a, b) for a, b in zip(before, trainer.agent.parameters()))
        assert stats["updates"] == steps and moved == (steps > 0)
        assert stats["approx_kl"] > 1.5e-12 and stats["kl"] != 0.0
    finally:
        trainer.close()
