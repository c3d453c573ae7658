"""Exploration noise of a Gaussian policy: white (independent at every step) or coloured.

The policy acts ``mean + std * eps``. With white noise ``eps`` is drawn afresh at every step: at
30 Hz, a jerk on every joint 30 times a second. Coloured noise (Eberhard et al.,
"Pink noise is all you need", ICLR 2023; for PPO: Hollenstein et al., "Colored noise in PPO",
AAAI 2024) keeps the same unit Gaussian at every step -- so PPO's per-step log-probabilities and
its ratio are unchanged -- but correlates it over time: its power spectrum falls as 1/f^beta over a
sequence of ``horizon`` steps (beta 0: white, 1: pink, 2: red, a random walk's). A new sequence
starts with every episode. (On the standing upper body, red noise of the same size costs the
controller less reward than white, but falls as often, and PPO learned worse under it:
docs/archive/upper_body_notes.md, "Probes on 69318".)
"""

from __future__ import annotations

import numpy as np
import torch


def powerlaw_noise(beta: float, size: int, horizon: int, rng: np.random.Generator) -> np.ndarray:
    """``(size, horizon)`` Gaussian sequences with power spectrum ~ 1/f^beta and unit variance at
    every step (Timmer & Koenig 1995, as the ``colorednoise`` package, whose normalisation leaves
    out the mean's term; the mean, a frequency a sequence this short cannot resolve, takes the
    spectrum's value at 1/horizon, as there)."""
    frequencies = np.fft.rfftfreq(horizon)
    scale = frequencies.copy()
    scale[0] = 1.0 / horizon
    scale = scale ** (-beta / 2.0)
    # The variance of every step of the inverse FFT below (the mean and, for an even horizon, the
    # Nyquist term are real and doubled; every other frequency counts twice): divided out exactly.
    variance = 2 * scale[0] ** 2 + 4 * np.sum(scale[1:-1] ** 2) + (2 if horizon % 2 == 0 else 4) * scale[-1] ** 2
    sigma = np.sqrt(variance) / horizon
    real = rng.normal(scale=scale, size=(size, len(frequencies)))
    imaginary = rng.normal(scale=scale, size=(size, len(frequencies)))
    if horizon % 2 == 0:  # the Nyquist component of a real signal is real
        imaginary[:, -1] = 0.0
        real[:, -1] *= np.sqrt(2)
    imaginary[:, 0] = 0.0  # so is the mean's
    real[:, 0] *= np.sqrt(2)
    return np.fft.irfft(real + 1j * imaginary, n=horizon, axis=-1) / sigma


class ActionNoise:
    """One environment's ``eps``: ``sample()`` gives the next step's ``(size,)`` draw.

    beta 0 draws from a torch generator seeded with ``seed`` (the white noise aslexp always drew,
    bit for bit); beta > 0 reads ``horizon``-step coloured sequences from a numpy generator seeded
    with ``seed``, a fresh one at every :meth:`restart` (an episode's start) and when one runs out.
    """

    def __init__(self, size: int, seed: int, beta: float = 0.0, horizon: int = 300) -> None:
        if beta < 0 or horizon < 2:
            raise ValueError(f"ppo config: noise_beta must be >= 0 and noise_horizon >= 2, got {beta}, {horizon}")
        self.size, self.beta, self.horizon = size, float(beta), int(horizon)
        self._generator = torch.Generator().manual_seed(seed) if self.beta == 0 else None
        self._rng = np.random.default_rng(seed) if self.beta > 0 else None
        self._sequence: np.ndarray | None = None
        self._index = 0

    def sample(self) -> torch.Tensor:
        if self._generator is not None:
            return torch.randn((1, self.size), generator=self._generator)[0]
        if self._sequence is None or self._index >= self.horizon:
            self._sequence = powerlaw_noise(self.beta, self.size, self.horizon, self._rng).astype(np.float32)
            self._index = 0
        self._index += 1
        return torch.from_numpy(np.ascontiguousarray(self._sequence[:, self._index - 1]))

    def restart(self) -> None:
        """A new episode: coloured noise starts a new sequence (white noise has none)."""
        self._sequence = None
