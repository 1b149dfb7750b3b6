"""The actor's action distribution, chosen from the env's action space.

A distribution head holds the actor's output network (a stateless function of the features the
actor's body computes) and maps its output to the distribution's parameters (entries a batch
stores, so the behaviour policy of a step can be rebuilt: CPO's KL to it); it builds the
distribution from them:

- ``gymnasium.spaces.Box``: :class:`GaussianHead`, a diagonal Gaussian in the env's action units
  with a state-independent log-std (the network works in [-1, 1]; the mean is rescaled to the box,
  the std is a fraction of the box's half-width). Samples are not squashed: the env clips them, so
  the log-probability of a stored action never meets a tanh saturation.
- ``gymnasium.spaces.Discrete``: :class:`CategoricalHead`, a categorical over the ``n`` actions on
  the network's logits. Its actions are stored as ``[..., 1]`` integer indices, like a box action
  of one dimension.

Every head samples by ``rsample`` where the distribution has one, else ``sample``, and its
deterministic action is the mode (the Gaussian's mean, the categorical's most likely action).
"""

from __future__ import annotations

import gymnasium as gym
import torch
from torch import distributions as D
from torch import nn
from torchrl.modules import IndependentNormal

from cmdp_rl import keys


class GaussianHead(nn.Module):
    """``net(features)`` in [-1, 1] -> ``(loc, scale)`` in the env's action units; a diagonal Gaussian."""

    param_keys = (keys.LOC, keys.SCALE)

    def __init__(self, net: nn.Module, low: torch.Tensor, high: torch.Tensor, init_log_std: float) -> None:
        super().__init__()
        self.net = net
        self.register_buffer("center", (high + low) / 2)
        self.register_buffer("half_width", (high - low) / 2)
        self.log_std = nn.Parameter(torch.full_like(low, init_log_std))

    def forward(self, *features: torch.Tensor) -> dict[str, torch.Tensor]:
        loc = self.center + self.half_width * self.net(*features)
        scale = (self.half_width * self.log_std.exp()).expand_as(loc)
        return {keys.LOC: loc, keys.SCALE: scale}

    @staticmethod
    def dist(params: dict[str, torch.Tensor]) -> D.Distribution:
        return IndependentNormal(params[keys.LOC], params[keys.SCALE])


class Categorical(D.Categorical):
    """``torch.distributions.Categorical`` on actions stored as ``[..., 1]`` indices."""

    def sample(self, sample_shape: torch.Size = torch.Size()) -> torch.Tensor:
        return super().sample(sample_shape).unsqueeze(-1)

    def log_prob(self, value: torch.Tensor) -> torch.Tensor:
        return super().log_prob(value.squeeze(-1))

    @property
    def deterministic_sample(self) -> torch.Tensor:
        return self.probs.argmax(-1, keepdim=True)


class CategoricalHead(nn.Module):
    """``net(features)`` -> logits of a categorical over the actions."""

    param_keys = (keys.LOGITS,)

    def __init__(self, net: nn.Module) -> None:
        super().__init__()
        self.net = net

    def forward(self, *features: torch.Tensor) -> dict[str, torch.Tensor]:
        return {keys.LOGITS: self.net(*features)}

    @staticmethod
    def dist(params: dict[str, torch.Tensor]) -> D.Distribution:
        return Categorical(logits=params[keys.LOGITS])


def action_outputs(space: gym.Space) -> int:
    """How many outputs the actor's network needs for ``space``: the box's dimension (the mean), or
    one logit per action."""
    if isinstance(space, gym.spaces.Box):
        return int(space.low.size)
    if isinstance(space, gym.spaces.Discrete):
        return int(space.n)
    raise ValueError(f"policy: no action distribution for {type(space).__name__} action spaces (Box, Discrete)")


def make_action_head(space: gym.Space, net: nn.Module, init_log_std: float = -0.5) -> GaussianHead | CategoricalHead:
    """The distribution head for ``space`` around the output network ``net`` (``init_log_std``: the
    Gaussian's initial log-std, in units of the box's half-width)."""
    if isinstance(space, gym.spaces.Box):
        low = torch.as_tensor(space.low, dtype=torch.float32).reshape(-1)
        high = torch.as_tensor(space.high, dtype=torch.float32).reshape(-1)
        return GaussianHead(net, low, high, init_log_std)
    if isinstance(space, gym.spaces.Discrete):
        return CategoricalHead(net)
    raise ValueError(f"policy: no action distribution for {type(space).__name__} action spaces (Box, Discrete)")


def sample(dist: D.Distribution, deterministic: bool) -> torch.Tensor:
    """The action: the mode if ``deterministic``, else a sample (``rsample`` where it exists)."""
    if deterministic:
        return dist.deterministic_sample
    return dist.rsample() if dist.has_rsample else dist.sample()


__all__ = ["Categorical", "CategoricalHead", "GaussianHead", "action_outputs", "make_action_head", "sample"]
