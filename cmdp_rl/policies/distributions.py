"""The actor's action distribution, chosen from the env's action space: :class:`GaussianHead` on a ``Box`` (in
the env's units, unsquashed: the env clips, so a stored action's log-probability never meets a tanh saturation),
:class:`CategoricalHead` on ``Discrete``/``MultiDiscrete`` (indices), ``HybridHead`` on a skill and its
parameters. A head maps its output network's output to the parameters a batch stores (CPO's KL reads them)."""

from __future__ import annotations

import math

import gymnasium as gym
import torch
from torch import distributions as D
from torch import nn
from torch.distributions import constraints, kl_divergence, register_kl
from torchrl.modules import IndependentNormal

from cmdp_rl.policies.hybrid import HybridHead
from cmdp_rl.rollout import keys
from cmdp_rl.rollout.actions import action_bounds, categories, check_action_space, hybrid

_LOG_SQRT_2PI = math.log(math.sqrt(2 * math.pi))  # Normal.log_prob's constant, computed as it computes it


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
        return self.params(self.net(*features), self.log_std)

    def params(self, out: torch.Tensor, log_std: torch.Tensor) -> dict[str, torch.Tensor]:
        """``(loc, scale)`` from ``out`` and ``log_std`` (a population's stacked ones, ``[P, 1, A]``)."""
        loc = self.center + self.half_width * out
        return {keys.LOC: loc, keys.SCALE: (self.half_width * log_std.exp()).expand_as(loc)}

    @staticmethod
    def dist(params: dict[str, torch.Tensor]) -> D.Distribution:
        return IndependentNormal(params[keys.LOC], params[keys.SCALE])

    @staticmethod
    def act(params: dict[str, torch.Tensor], deterministic: bool) -> tuple[torch.Tensor, torch.Tensor]:
        """The action and log-probability ``sample(dist(params), deterministic)`` gives, op for op and draw for draw,
        without building the distribution (its validation and wrapping cost more than the network every step)."""
        loc, scale = params[keys.LOC], params[keys.SCALE]
        action = loc if deterministic else loc + torch.empty_like(loc).normal_() * scale
        log_prob = -((action - loc) ** 2) / (2 * scale**2) - scale.log() - _LOG_SQRT_2PI
        return action, log_prob.sum(-1)


class Categorical(D.Categorical):
    """``torch.distributions.Categorical`` on actions stored as ``[..., 1]`` indices."""

    def sample(self, sample_shape: torch.Size = torch.Size()) -> torch.Tensor:
        return super().sample(sample_shape).unsqueeze(-1)

    def log_prob(self, value: torch.Tensor) -> torch.Tensor:
        return super().log_prob(value.squeeze(-1))

    @property
    def deterministic_sample(self) -> torch.Tensor:
        return self.probs.argmax(-1, keepdim=True)


class MultiCategorical(D.Distribution):
    """Independent categoricals on logits ``[..., sum(sizes)]`` split by ``sizes``; values ``[..., m]`` indices."""

    arg_constraints = {"logits": constraints.real_vector}
    has_rsample = False

    def __init__(self, logits: torch.Tensor, sizes: tuple[int, ...], validate_args: bool | None = None) -> None:
        self.logits = logits
        self.sizes = tuple(sizes)
        self.parts = [D.Categorical(logits=part) for part in logits.split(self.sizes, dim=-1)]
        super().__init__(logits.shape[:-1], torch.Size([len(self.sizes)]), validate_args=False)

    def sample(self, sample_shape: torch.Size = torch.Size()) -> torch.Tensor:
        return torch.stack([p.sample(sample_shape) for p in self.parts], dim=-1)

    def log_prob(self, value: torch.Tensor) -> torch.Tensor:
        return sum(p.log_prob(v) for p, v in zip(self.parts, value.unbind(-1)))

    def entropy(self) -> torch.Tensor:
        return sum(p.entropy() for p in self.parts)

    @property
    def deterministic_sample(self) -> torch.Tensor:
        """Each component's most likely index: the joint mode, the components being independent."""
        return torch.stack([p.probs.argmax(-1) for p in self.parts], dim=-1)

    @property
    def mode(self) -> torch.Tensor:
        return self.deterministic_sample


@register_kl(MultiCategorical, MultiCategorical)
def _kl_multi_categorical(p: MultiCategorical, q: MultiCategorical) -> torch.Tensor:
    """KL of independent products: the sum of the components' KLs."""
    return sum(kl_divergence(a, b) for a, b in zip(p.parts, q.parts))


class CategoricalHead(nn.Module):
    """``net(features)`` -> the logits of one categorical, or of ``len(sizes)`` (a ``MultiDiscrete``)."""

    param_keys = (keys.LOGITS,)

    def __init__(self, net: nn.Module, sizes: tuple[int, ...] | None = None) -> None:
        super().__init__()
        self.net = net
        self.sizes = None if sizes is None else tuple(sizes)

    def forward(self, *features: torch.Tensor) -> dict[str, torch.Tensor]:
        return self.params(self.net(*features))

    def params(self, out: torch.Tensor, log_std: None = None) -> dict[str, torch.Tensor]:
        return {keys.LOGITS: out}

    def dist(self, params: dict[str, torch.Tensor]) -> D.Distribution:
        if self.sizes is None:
            return Categorical(logits=params[keys.LOGITS])
        return MultiCategorical(params[keys.LOGITS], self.sizes)


def action_outputs(space: gym.Space) -> int:
    """How many outputs the actor's network needs for ``space``: the box's means, the logits, or both."""
    check_action_space(space)
    if hybrid(space) is not None:
        return HybridHead.outputs(hybrid(space))
    if isinstance(space, gym.spaces.Box):
        return int(space.low.size)
    return sum(categories(space))


def make_action_head(
    space: gym.Space, net: nn.Module, init_log_std: float = -0.5
) -> GaussianHead | CategoricalHead | HybridHead:
    """The head for ``space`` around ``net`` (``init_log_std`` in units of the box's half-width)."""
    check_action_space(space)
    if hybrid(space) is not None:
        return HybridHead(net, hybrid(space), init_log_std)
    if isinstance(space, gym.spaces.Box):
        return GaussianHead(net, *action_bounds(space), init_log_std)
    if isinstance(space, gym.spaces.Discrete):
        return CategoricalHead(net)
    return CategoricalHead(net, categories(space))


def sample(dist: D.Distribution, deterministic: bool) -> torch.Tensor:
    """The action: the mode if ``deterministic``, else a sample (``rsample`` where it exists)."""
    if deterministic:
        return dist.deterministic_sample
    return dist.rsample() if dist.has_rsample else dist.sample()
