"""What a policy network reads: the observation and, optionally, the previous action and cost, the parts of the
history the observation lacks (a memory policy can integrate its own motion and notice when it paid a cost; the
previous cost as in Stooke, Achiam, Abbeel, 2020, sec. 6). The collector writes them at the root for any policy
whose ``in_keys`` ask for them (zero on an episode's first step)."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import torch
from torch import nn
from torch.nn import functional as F

from cmdp_rl.rollout import keys
from cmdp_rl.rollout.actions import action_bounds, action_dim, categories, is_discrete


def input_keys(include_prev_action: bool, include_prev_cost: bool) -> list[str]:
    """The root entries a network reads, in the order :class:`InputEncoder` takes them."""
    return [keys.OBS] + [keys.PREV_ACTION] * include_prev_action + [keys.PREV_COST] * include_prev_cost


class InputEncoder(nn.Module):
    """``cat(normalized obs, previous action, previous costs [K])``: a box's action scaled to ``[-1, 1]`` and clipped as
    the env clips it, a discrete one one-hot per component (all zeros for the first step's -1). ``in_dim``: the raw
    inputs' width (a transformer's token); ``out_dim``: the encoding's."""

    def __init__(
        self,
        obs_dim: int,
        action_space: gym.Space,
        include_prev_action: bool,
        include_prev_cost: bool,
        obs_norm: nn.Module | None = None,
        num_costs: int = 1,
    ) -> None:
        super().__init__()
        self.obs_norm = obs_norm
        self.include_prev_action = include_prev_action
        self.include_prev_cost = include_prev_cost
        self.num_costs = num_costs  # the previous cost is the vector of the env's K costs
        self.categories = categories(action_space) if is_discrete(action_space) else None
        if self.categories is None:
            low, high = action_bounds(action_space)  # a hybrid action's skill index too
            self.register_buffer("center", (high + low) / 2)
            self.register_buffer("half_width", (high - low) / 2)
        encoded = action_dim(action_space) if self.categories is None else sum(self.categories)
        cost = num_costs if include_prev_cost else 0
        self.in_dim = obs_dim + (action_dim(action_space) if include_prev_action else 0) + cost
        self.out_dim = obs_dim + (encoded if include_prev_action else 0) + cost

    @classmethod
    def of(cls, cfg: Any, env: Any, obs_norm: nn.Module | None) -> InputEncoder:
        """The encoder ``cfg``'s ``include_prev_action`` and ``include_prev_cost`` ask for on ``env``."""
        return cls(
            env.obs_dim, env.action_space, cfg.include_prev_action, cfg.include_prev_cost, obs_norm, env.num_costs
        )

    def encode_action(self, action: torch.Tensor) -> torch.Tensor:
        if self.categories is None:
            return ((action - self.center) / self.half_width).clamp(-1.0, 1.0)
        # index + 1 over n + 1 classes, the first ("none") dropped: -1 encodes as all zeros.
        idx = action.long() + 1
        return torch.cat(
            [F.one_hot(i, n + 1)[..., 1:] for i, n in zip(idx.unbind(-1), self.categories)], dim=-1
        ).float()

    def forward(self, obs: torch.Tensor, *prev: torch.Tensor) -> torch.Tensor:
        parts = [obs if self.obs_norm is None else self.obs_norm(obs)]
        rest = list(prev)
        if self.include_prev_action:
            parts.append(self.encode_action(rest.pop(0)))
        if self.include_prev_cost:
            parts.append(rest.pop(0))
        return parts[0] if len(parts) == 1 else torch.cat(parts, dim=-1)
