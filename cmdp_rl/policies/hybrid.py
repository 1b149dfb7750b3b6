"""The action distribution of a hybrid action space, one ``Discrete(n)`` skill and a ``Box`` of its ``p`` parameters
(``rollout.actions.hybrid``): ``pi(k, x | s) = pi_hi(k | s) pi_lo(x | s, k)``, a categorical times the chosen skill's
diagonal Gaussian (state-independent std), with exact log-probability, entropy and KL by the chain rules
(docs/multi_agent_and_hybrid.md); the KL is registered with torch for CPO's Fisher-vector product. By hand: torch has
no distribution whose continuous part is conditioned on the discrete one. Stored actions are float ``[..., 1 + p]``:
the skill index, then the parameters in the box's units (the env clips)."""

from __future__ import annotations

import torch
from torch import distributions as D
from torch import nn
from torch.distributions import constraints, kl_divergence, register_kl

from cmdp_rl.rollout import keys
from cmdp_rl.rollout.actions import Hybrid, action_bounds


class SkillParameters(D.Distribution):
    """``pi(k, x) = Cat(k; logits) N(x; loc[k], scale[k])``: ``logits`` ``[..., n]``, ``loc`` and
    ``scale`` ``[..., n, p]``; values ``[..., 1 + p]`` (skill index as a float, then ``x``)."""

    arg_constraints = {"logits": constraints.real_vector}
    has_rsample = False

    def __init__(self, logits: torch.Tensor, loc: torch.Tensor, scale: torch.Tensor) -> None:
        self.skill = D.Categorical(logits=logits)
        self.params = D.Independent(D.Normal(loc, scale), 1)  # batch [..., n], event [p]
        self.loc, self.scale = loc, scale
        super().__init__(logits.shape[:-1], torch.Size([1 + loc.shape[-1]]), validate_args=False)

    def _of_skill(self, t: torch.Tensor, k: torch.Tensor) -> torch.Tensor:
        """``t[..., k, :]`` for each batch entry's skill ``k`` ``[...]`` (``t`` broadcast to ``k``'s batch)."""
        t = t.expand(*torch.broadcast_shapes(t.shape[:-2], k.shape), *t.shape[-2:])
        k = k.expand(t.shape[:-2])
        index = k[..., None, None].expand(*k.shape, 1, t.shape[-1])
        return t.gather(-2, index).squeeze(-2)

    def sample(self, sample_shape: torch.Size = torch.Size()) -> torch.Tensor:
        if sample_shape != torch.Size():
            raise ValueError("SkillParameters samples one action per batch entry")
        with torch.no_grad():
            k = self.skill.sample()
            x = torch.normal(self._of_skill(self.loc, k), self._of_skill(self.scale, k))
        return torch.cat([k.unsqueeze(-1).to(x.dtype), x], dim=-1)

    def log_prob(self, value: torch.Tensor) -> torch.Tensor:
        k = value[..., 0].round().long()
        x = value[..., 1:]
        normal = D.Independent(D.Normal(self._of_skill(self.loc, k), self._of_skill(self.scale, k)), 1)
        return self.skill.log_prob(k) + normal.log_prob(x)

    def entropy(self) -> torch.Tensor:
        return self.skill.entropy() + (self.skill.probs * self.params.entropy()).sum(-1)

    @property
    def deterministic_sample(self) -> torch.Tensor:
        """The most likely skill and its parameters' mean."""
        k = self.skill.probs.argmax(-1)
        return torch.cat([k.unsqueeze(-1).to(self.loc.dtype), self._of_skill(self.loc, k)], dim=-1)

    @property
    def mode(self) -> torch.Tensor:
        return self.deterministic_sample


@register_kl(SkillParameters, SkillParameters)
def _kl_skill_parameters(p: SkillParameters, q: SkillParameters) -> torch.Tensor:
    """The chain rule: the skills' KL plus each skill's Gaussian KL weighted by ``p``'s skill probability."""
    return kl_divergence(p.skill, q.skill) + (p.skill.probs * kl_divergence(p.params, q.params)).sum(-1)


class HybridHead(nn.Module):
    """``net(features)`` -> ``n`` skill logits and ``n x p`` means rescaled to the box; ``n x p`` log-stds."""

    param_keys = (keys.LOGITS, keys.LOC, keys.SCALE)

    def __init__(self, net: nn.Module, parts: Hybrid, init_log_std: float) -> None:
        super().__init__()
        self.net = net
        self.skills = parts.skills
        low, high = action_bounds(parts.box)
        self.register_buffer("center", (high + low) / 2)
        self.register_buffer("half_width", (high - low) / 2)
        self.log_std = nn.Parameter(torch.full((parts.skills, low.numel()), init_log_std))

    @staticmethod
    def outputs(parts: Hybrid) -> int:
        """The network's outputs: one logit per skill, one mean per skill and parameter."""
        return parts.skills * (1 + int(parts.box.low.size))

    def forward(self, *features: torch.Tensor) -> dict[str, torch.Tensor]:
        out = self.net(*features)
        n, p = self.log_std.shape
        logits, mean = out.split([n, n * p], dim=-1)
        loc = self.center + self.half_width * mean.unflatten(-1, (n, p))
        scale = (self.half_width * self.log_std.exp()).expand_as(loc)
        return {keys.LOGITS: logits, keys.LOC: loc, keys.SCALE: scale}

    @staticmethod
    def dist(params: dict[str, torch.Tensor]) -> SkillParameters:
        return SkillParameters(params[keys.LOGITS], params[keys.LOC], params[keys.SCALE])
