"""Exploration noise: white noise is the stream aslexp always drew; coloured noise keeps a unit
Gaussian at every step (PPO's log-probabilities stay right) with the power spectrum it names, is
seeded, restarts with every episode, and reaches the actions in every collection mode."""

from __future__ import annotations

import functools

import numpy as np
import pytest
import torch

from aslexp.envs.imitation import ImitationEnv
from aslexp.rl.noise import ActionNoise, powerlaw_noise
from aslexp.rl.ppo import PPOConfig, PPOTrainer


def test_white_noise_is_the_torch_stream_drawn_before_noise_had_a_colour():
    noise = ActionNoise(5, seed=123)
    generator = torch.Generator().manual_seed(123)
    for _ in range(4):
        assert torch.equal(noise.sample(), torch.randn((1, 5), generator=generator)[0])


@pytest.mark.parametrize("beta", [0.5, 1.0, 2.0])
def test_coloured_noise_has_unit_variance_and_the_spectrum_it_names(beta):
    rng = np.random.default_rng(0)
    noise = powerlaw_noise(beta, 2000, 256, rng)  # 2000 sequences of 256 steps
    assert noise.shape == (2000, 256)
    per_step_std = noise.std(axis=0)  # over sequences, at each step: the marginal PPO assumes
    assert abs(noise.mean()) < 0.05 and np.all(np.abs(per_step_std - 1) < 0.1), per_step_std.min()
    power = (np.abs(np.fft.rfft(noise, axis=-1)) ** 2).mean(axis=0)[1:-1]
    frequencies = np.fft.rfftfreq(256)[1:-1]
    slope = np.polyfit(np.log(frequencies), np.log(power), 1)[0]
    assert abs(slope + beta) < 0.1, slope


def test_the_colour_correlates_consecutive_steps():
    lag1 = {}
    for beta in (0.0, 0.5, 1.0, 2.0):
        x = powerlaw_noise(beta, 500, 300, np.random.default_rng(1)) if beta else np.random.default_rng(1).normal(
            size=(500, 300))
        lag1[beta] = float(np.mean(x[:, 1:] * x[:, :-1]) / np.mean(x * x))
    assert abs(lag1[0.0]) < 0.02 and lag1[0.0] < lag1[0.5] < lag1[1.0] < lag1[2.0] and lag1[2.0] > 0.9, lag1


def test_coloured_noise_is_seeded_restarts_and_continues_past_its_horizon():
    def draws(noise, n):
        return torch.stack([noise.sample() for _ in range(n)])

    a, b = ActionNoise(3, seed=7, beta=1.0, horizon=8), ActionNoise(3, seed=7, beta=1.0, horizon=8)
    first = draws(a, 20)  # two and a half sequences
    assert first.shape == (20, 3) and torch.equal(first, draws(b, 20))
    assert not torch.equal(first[:8], first[8:16])  # a new sequence when one runs out
    c = ActionNoise(3, seed=7, beta=1.0, horizon=8)
    draws(c, 3)
    c.restart()  # an episode ended after 3 steps: the rest of its sequence is dropped
    assert torch.equal(draws(c, 8), first[8:16])
    with pytest.raises(ValueError, match="noise_beta"):
        ActionNoise(3, seed=0, beta=-1.0)
    with pytest.raises(ValueError, match="noise_horizon must be at least 2"):
        PPOConfig(noise_horizon=1)


def test_in_process_and_worker_collection_draw_the_same_coloured_noise(tmp_path, motion_a):
    # The same seeds give the same pink noise whether the environments step in this process
    # (vector_env=sync) or in rollout workers: the actions agree, and their noise is correlated.
    make_env = functools.partial(ImitationEnv, motion_a, env={"episode_steps": 15})
    tiny = dict(hidden_sizes=(16, 16), steps_per_rollout=64, log_std_init=-1.0, num_envs=2, noise_horizon=16,
                device="cpu")
    batches = {}
    for mode, beta in (("sync", 1.0), ("workers", 1.0), ("sync", 0.0)):
        config = PPOConfig(**tiny, vector_env=mode, noise_beta=beta)
        trainer = PPOTrainer(make_env, None, config, tmp_path / f"{mode}{beta}", seed=5)
        try:
            batches[mode, beta] = trainer.collect()
        finally:
            trainer.close()
    sync, workers = batches["sync", 1.0], batches["workers", 1.0]
    assert torch.allclose(sync["action"], workers["action"], atol=1e-5)
    assert torch.allclose(sync["next", "reward"], workers["next", "reward"], atol=1e-5)

    def lag1(actions: torch.Tensor) -> float:  # the policy's mean moves little at initialisation
        centred = actions - actions.mean(dim=1, keepdim=True)
        return float((centred[:, 1:] * centred[:, :-1]).mean() / (centred * centred).mean())

    white, pink = lag1(batches["sync", 0.0]["action"]), lag1(sync["action"])
    assert abs(white) < 0.15 and pink > white + 0.25, (white, pink)
