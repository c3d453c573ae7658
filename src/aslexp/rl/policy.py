"""The agent's model: observation normaliser, Gaussian MLP actor, MLP critic (torchrl modules).

The actor samples ``a ~ Normal(mlp(obs), exp(log_std))`` with a state-independent, learned log
standard deviation (as in the thesis' Stable-Baselines3 policy), and ``action_mapping`` turns it into
the environment's action: ``box`` (aslexp's) maps the unit Gaussian affinely onto the action box,
``center + half_range * a`` (a fresh policy's targets sit at the box's centre, ~1 rad for the hand's
joints); ``sb3`` does what SB3 1.6 does with a Box action space, the authors' library: ``a`` is in
the action's own units and clipped to the box (a fresh policy's targets sit near 0: an open hand).
The log-probability is always the unclipped sample's, as in SB3. Observations are
normalised by running statistics held in the agent (the learner), updated from each rollout's
observations of all environments at once: merging per-worker statistics would give the same
mean and variance (the parallel-variance update is exact); rollout workers receive them, frozen
for the rollout, with the weights.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.modules import IndependentNormal, ProbabilisticActor, ValueOperator

ACTIVATIONS = {"relu": nn.ReLU, "tanh": nn.Tanh, "elu": nn.ELU}
ACTION_MAPPINGS = ("box", "sb3")


class RunningNormalizer(nn.Module):
    """Running mean and variance of observations (parallel-variance update), with clipping."""

    def __init__(self, size: int, clip: float = 10.0, eps: float = 1e-8) -> None:
        super().__init__()
        self.register_buffer("mean", torch.zeros(size, dtype=torch.float64))
        self.register_buffer("var", torch.ones(size, dtype=torch.float64))
        self.register_buffer("count", torch.tensor(eps, dtype=torch.float64))
        self.clip = clip
        self.eps = eps

    @torch.no_grad()
    def update(self, batch: torch.Tensor) -> None:
        batch = batch.reshape(-1, self.mean.shape[0]).to(torch.float64)
        b_mean, b_var, b_count = batch.mean(0), batch.var(0, unbiased=False), batch.shape[0]
        delta = b_mean - self.mean
        total = self.count + b_count
        self.mean += delta * b_count / total
        m2 = self.var * self.count + b_var * b_count + delta.pow(2) * self.count * b_count / total
        self.var = m2 / total
        self.count = total

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        normed = (obs.to(torch.float64) - self.mean) / torch.sqrt(self.var + self.eps)
        return normed.clamp(-self.clip, self.clip).to(obs.dtype)

    def numpy(self, obs: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return self(torch.as_tensor(obs, dtype=torch.float32)).numpy()


def mlp(in_size: int, hidden: list[int], out_size: int, activation: str, ortho: bool, out_gain: float) -> nn.Sequential:
    layers: list[nn.Module] = []
    size = in_size
    for width in hidden:
        linear = nn.Linear(size, width)
        if ortho:
            nn.init.orthogonal_(linear.weight, gain=np.sqrt(2))
            nn.init.zeros_(linear.bias)
        layers += [linear, ACTIVATIONS[activation]()]
        size = width
    head = nn.Linear(size, out_size)
    if ortho:
        nn.init.orthogonal_(head.weight, gain=out_gain)
        nn.init.zeros_(head.bias)
    layers.append(head)
    return nn.Sequential(*layers)


class GaussianHead(nn.Module):
    """obs -> (loc, scale) with a learned, state-independent log standard deviation."""

    def __init__(self, net: nn.Module, action_size: int, log_std_init: float) -> None:
        super().__init__()
        self.net = net
        self.log_std = nn.Parameter(torch.full((action_size,), float(log_std_init)))

    def forward(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        loc = self.net(obs)
        return loc, self.log_std.exp().expand_as(loc)


@dataclass(frozen=True)
class ModelSpec:
    hidden_sizes: tuple[int, ...] = (1024, 1024)
    activation: str = "relu"
    ortho_init: bool = True
    log_std_init: float = -3.0
    # The actor's own hidden sizes (None: hidden_sizes; (): a linear policy, the critic keeps its MLP).
    actor_hidden_sizes: tuple[int, ...] | None = None
    action_mapping: str = "box"  # box (aslexp: affine onto the box) | sb3 (SB3 1.6: raw units, clipped)


class Agent(nn.Module):
    """Normaliser + actor + critic; ``actor`` and ``critic`` are torchrl modules for the loss."""

    def __init__(self, obs_size: int, action_size: int, spec: ModelSpec,
                 action_center: np.ndarray, action_half_range: np.ndarray) -> None:
        super().__init__()
        self.spec = spec
        self.normalizer = RunningNormalizer(obs_size)
        hidden = list(spec.hidden_sizes)
        actor_hidden = hidden if spec.actor_hidden_sizes is None else list(spec.actor_hidden_sizes)
        head = GaussianHead(mlp(obs_size, actor_hidden, action_size, spec.activation, spec.ortho_init, 0.01),
                            action_size, spec.log_std_init)
        self.actor = ProbabilisticActor(
            TensorDictModule(head, in_keys=["observation"], out_keys=["loc", "scale"]),
            in_keys=["loc", "scale"], distribution_class=IndependentNormal, return_log_prob=True,
        )
        self.critic = ValueOperator(mlp(obs_size, hidden, 1, spec.activation, spec.ortho_init, 1.0),
                                    in_keys=["observation"])
        if spec.action_mapping not in ACTION_MAPPINGS:
            raise ValueError(f"ppo config: action_mapping must be one of {ACTION_MAPPINGS}, got {spec.action_mapping!r}")
        self.register_buffer("action_center", torch.as_tensor(action_center, dtype=torch.float32))
        self.register_buffer("action_half_range", torch.as_tensor(action_half_range, dtype=torch.float32))

    @property
    def head(self) -> GaussianHead:
        """The actor's network: normalised observation -> (loc, scale) of the normalised action."""
        return self.actor.module[0].module

    @property
    def device(self) -> torch.device:
        return self.action_center.device

    def to_env_action(self, sample: torch.Tensor) -> torch.Tensor:
        """The environment's action for a policy sample (module docstring: ``action_mapping``)."""
        if self.spec.action_mapping == "sb3":
            return torch.clamp(sample, self.action_center - self.action_half_range,
                               self.action_center + self.action_half_range)
        return self.action_center + self.action_half_range * sample

    @torch.no_grad()
    def act(self, obs: np.ndarray, deterministic: bool = True) -> np.ndarray:
        """Environment action(s) for raw observation(s) (mean action when deterministic)."""
        x = self.normalizer(torch.as_tensor(obs, dtype=torch.float32, device=self.device))
        loc, scale = self.head(x)
        a = loc if deterministic else loc + scale * torch.randn_like(loc)
        return self.to_env_action(a).cpu().numpy()
